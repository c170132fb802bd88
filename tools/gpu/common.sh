# Shared by the scripts that run on a lent GPU (sourced from the repository root).

# The Vulkan loader and glvnd packages carried in .gl/ (tools/gpu/prepare.sh), unpacked into the
# machine, and NVIDIA's ICD named where the image does not list it.
vulkan_env() {
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
    local icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    if [ -f "$icd" ] && ! ls /usr/share/vulkan/icd.d/*nvidia* /etc/vulkan/icd.d/*nvidia* >/dev/null 2>&1; then
        export VK_DRIVER_FILES=$icd
    fi
}

# Lines with the wall-clock time in front (training logs give whole seconds only).
stamp() { while IFS= read -r l; do echo "$(date +%s.%N | cut -c1-14) $l"; done; }
