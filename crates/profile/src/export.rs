//! A profile's camera numbers in the forms single-molecule localization tools take: their users
//! type a baseline, a conversion and an EM gain into each tool by hand today, and the tools
//! disagree on names and even on the direction of the conversion (their own help texts, against
//! their code). Every tool here converts as `photons = (ADU − baseline) · e_per_ADU / EM gain`,
//! with `e_per_ADU` the electrons per A/D count *before* the EM register; a profile's one
//! conversion is `K = s/2` DN per photo-electron, so `e_per_ADU = G / K`.

use crate::{CameraProfile, Error, Result};

/// The tools a profile is exported to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tool {
    /// Picasso (jungmannlab): a camera entry for its `config.yaml` (`Cameras:`).
    Picasso,
    /// ThunderSTORM (ImageJ): a `Camera setup` macro call.
    Thunderstorm,
    /// DECODE (TuragaLab): the `Camera:` block of its parameter YAML.
    Decode,
    /// SMAP (Ries lab): the Camera Manager's fixed values, as MATLAB assignments.
    Smap,
}

impl std::str::FromStr for Tool {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Tool, String> {
        match s.to_ascii_lowercase().as_str() {
            "picasso" => Ok(Tool::Picasso),
            "thunderstorm" => Ok(Tool::Thunderstorm),
            "decode" => Ok(Tool::Decode),
            "smap" => Ok(Tool::Smap),
            _ => Err(format!(
                "{s}: the tools are picasso, thunderstorm, decode and smap"
            )),
        }
    }
}

/// What a profile does not hold but an export may: the EM gain setting where the profile does
/// not record it, and the pixel size in the sample.
#[derive(Clone, Copy, Debug, Default)]
pub struct Extra {
    /// EM gain setting (overrides the profile's).
    pub em_gain: Option<f64>,
    /// Pixel size in the sample, nm.
    pub pixel_size_nm: Option<f64>,
}

/// The numbers every export is made of.
struct Numbers {
    name: String,
    baseline: f64,
    em_gain: f64,
    e_per_adu: f64,
    read_sigma_dn: f64,
    spurious_e: Option<f64>,
}

fn numbers(p: &CameraProfile, extra: &Extra) -> Result<Numbers> {
    let k = p.dn_per_electron()?;
    // K holds at the gain the profile was made at: another gain is another profile.
    if let Some(g) = extra.em_gain.filter(|&g| p.em_gain > 0.0 && g != p.em_gain) {
        return Err(Error::Parameter(format!(
            "--em-gain {g}: the profile was calibrated at EM gain {}, and its DN per photoelectron holds at that gain only; calibrate (or characterize) the camera at EM gain {g}",
            p.em_gain
        )));
    }
    let em_gain = extra.em_gain.unwrap_or(p.em_gain);
    if !(em_gain >= 1.0 && em_gain.is_finite()) {
        return Err(Error::Parameter(
            "the profile does not record the EM gain setting (one characterized from a recording whose header has none): pass --em-gain, the camera's setting when it recorded".into(),
        ));
    }
    if !p.has_bias() {
        return Err(Error::Parameter(
            "the profile has no bias maps: calibrate it with bias stacks".into(),
        ));
    }
    Ok(Numbers {
        name: p.camera.clone(),
        baseline: p.bias_dn(),
        em_gain,
        e_per_adu: em_gain / k,
        read_sigma_dn: p.read_noise_dn(),
        spurious_e: p.pgn.as_ref().map(|g| g.cic_e),
    })
}

/// `profile` as `tool` takes it: the text of a file (or a macro line) with its units in comments.
pub fn export(profile: &CameraProfile, tool: Tool, extra: &Extra) -> Result<String> {
    let n = numbers(profile, extra)?;
    let header = format!(
        "emccd camera export: {} (fingerprint {}); photons = (ADU - baseline) * e_per_ADU / EM gain, e_per_ADU = EM gain / K, K = {:.4} DN per photoelectron",
        ascii(&n.name),
        profile.fingerprint_hex(),
        n.em_gain / n.e_per_adu
    );
    let px = extra.pixel_size_nm;
    let no_px = "pixel size: not in a camera profile; add it (nm in the sample)";
    Ok(match tool {
        Tool::Picasso => {
            let mut s = format!(
                "# {header}\n# Picasso reads photons = (ADU - Baseline) * Sensitivity / Gain, Gain being the EM gain of the run.\nCameras:\n  {}:\n",
                yaml_key(&n.name)
            );
            match px {
                Some(v) => s.push_str(&format!("    Pixelsize: {v}  # nm\n")),
                None => s.push_str(&format!("    # {no_px}\n")),
            }
            s.push_str(&format!(
                "    Baseline: {}  # ADU, the mean dark count\n    Sensitivity: {}  # electrons per ADU, before EM gain\n    DefaultGain: {}  # the EM gain setting the profile was calibrated at\n    Quantum Efficiency: 1  # the profile counts photoelectrons\n",
                num(n.baseline),
                num(n.e_per_adu),
                num(n.em_gain)
            ));
            s
        }
        Tool::Decode => {
            let mut s = format!("# {header}\nCamera:\n");
            s.push_str(&format!(
                "  baseline: {}  # ADU\n  convert2photons: true\n  e_per_adu: {}  # electrons per ADU, before EM gain\n  em_gain: {}\n",
                num(n.baseline),
                num(n.e_per_adu),
                num(n.em_gain)
            ));
            match px {
                Some(v) => s.push_str(&format!("  px_size: [{v}, {v}]  # nm\n")),
                None => s.push_str(&format!("  # {no_px}: px_size: [x, y]\n")),
            }
            s.push_str(&format!(
                "  qe: 1.0  # the profile counts photoelectrons\n  read_sigma: {}  # electrons after the EM register ({} DN)\n  spur_noise: {}  # {}\n",
                num(n.read_sigma_dn * n.e_per_adu),
                num(n.read_sigma_dn),
                num(n.spurious_e.unwrap_or(0.0)),
                if n.spurious_e.is_some() {
                    "clock-induced charge, electrons per pixel per frame"
                } else {
                    "not measured by this profile (characterized from a recording): the data sheet's clock-induced charge, or 0"
                }
            ));
            s
        }
        Tool::Thunderstorm => {
            let mut opts = format!(
                "offset={} quantumefficiency=1.0 isemgain=true photons2adu={} gainem={}",
                num(n.baseline),
                num(n.e_per_adu),
                num(n.em_gain)
            );
            if let Some(v) = px {
                opts.push_str(&format!(" pixelsize={v}"));
            }
            format!(
                "// {header}\n// offset: ADU; photons2adu: photoelectrons per A/D count (before EM gain); gainem: EM gain{}\nrun(\"Camera setup\", \"{opts}\");\n",
                if px.is_none() { format!("; {no_px} as pixelsize=") } else { String::new() }
            )
        }
        Tool::Smap => {
            let mut s = format!(
                "% {header}\n% SMAP's Camera Manager, fixed values: photons = (ADU - offset) * conversion / emgain.\nEMon = true;\nconversion = {};  % electrons per ADU, before EM gain\nemgain = {};\noffset = {};  % ADU\n",
                num(n.e_per_adu),
                num(n.em_gain),
                num(n.baseline)
            );
            match px {
                Some(v) => s.push_str(&format!(
                    "cam_pixelsize_um = [{} {}];  % um\n",
                    num(v / 1000.0),
                    num(v / 1000.0)
                )),
                None => s.push_str(&format!("% {no_px}: cam_pixelsize_um = [x y] in um\n")),
            }
            s
        }
    })
}

/// A number as the tools read it: enough digits, no exponent for ordinary values.
fn num(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s.is_empty() || s == "-" {
        "0".into()
    } else {
        s.to_string()
    }
}

/// `text` in ASCII (the tools' files are read as such).
fn ascii(text: &str) -> String {
    text.chars()
        .map(|c| {
            if c.is_ascii() && !c.is_ascii_control() {
                c
            } else {
                '?'
            }
        })
        .collect()
}

/// A camera name as a YAML mapping key: quoted, with quotes and backslashes escaped.
fn yaml_key(name: &str) -> String {
    format!(
        "\"{}\"",
        ascii(name).replace('\\', "\\\\").replace('"', "\\\"")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A key's number in an export (`key: v`, `key = v;` or `key=v`).
    fn value(text: &str, key: &str) -> f64 {
        for line in text
            .lines()
            .filter(|l| !l.trim_start().starts_with(['#', '%', '/']))
        {
            if let Some(at) = line.find(key) {
                let rest = line[at + key.len()..].trim_start_matches([':', '=', ' ']);
                let v: String = rest
                    .chars()
                    .take_while(|c| c.is_ascii_digit() || *c == '.' || *c == '-')
                    .collect();
                if let Ok(v) = v.parse() {
                    return v;
                }
            }
        }
        panic!("{key} not in\n{text}")
    }

    /// Every tool's own conversion of the exported numbers gives the profile's photoelectrons.
    #[test]
    fn each_tool_converts_to_the_profiles_photoelectrons() {
        let p = crate::default_profile();
        let k = p.dn_per_electron().unwrap();
        let adu = p.bias_dn() + 10.0 * k; // ten photoelectrons above the baseline
        let extra = Extra {
            em_gain: None,
            pixel_size_nm: Some(107.0),
        };
        for (tool, baseline, conversion, gain) in [
            (Tool::Picasso, "Baseline", "Sensitivity", "DefaultGain"),
            (Tool::Decode, "baseline", "e_per_adu", "em_gain"),
            (Tool::Thunderstorm, "offset", "photons2adu", "gainem"),
            (Tool::Smap, "offset", "conversion", "emgain"),
        ] {
            let t = export(&p, tool, &extra).unwrap();
            assert!(t.is_ascii(), "{tool:?}");
            let photons = (adu - value(&t, baseline)) * value(&t, conversion) / value(&t, gain);
            assert!((photons - 10.0).abs() < 1e-3, "{tool:?}: {photons}\n{t}");
            assert_eq!(value(&t, gain), 300.0, "{tool:?}");
        }
        let d = export(&p, Tool::Decode, &extra).unwrap();
        // DECODE's read noise is in electrons after the register: DN × e⁻ per ADU.
        let e_per_adu = value(&d, "e_per_adu");
        assert!((value(&d, "read_sigma") - p.read_noise_dn() * e_per_adu).abs() < 1e-3);
        assert_eq!(value(&d, "spur_noise"), p.pgn.as_ref().unwrap().cic_e);
        assert!(d.contains("px_size: [107, 107]"), "{d}");
        let s = export(&p, Tool::Smap, &extra).unwrap();
        assert!(s.contains("cam_pixelsize_um = [0.107 0.107];"), "{s}");
    }

    #[test]
    fn an_unknown_em_gain_is_asked_for() {
        let mut p = crate::default_profile();
        p.em_gain = 0.0;
        let e = export(&p, Tool::Decode, &Extra::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("--em-gain"), "{e}");
        let t = export(
            &p,
            Tool::Decode,
            &Extra {
                em_gain: Some(300.0),
                ..Default::default()
            },
        )
        .unwrap();
        assert!(t.contains("em_gain: 300"), "{t}");
        assert!(t.contains("# pixel size: not in a camera profile"), "{t}");
        // Another gain than the profile's own is refused: its K holds at its own gain.
        let p = crate::default_profile();
        let e = export(
            &p,
            Tool::Picasso,
            &Extra {
                em_gain: Some(1000.0),
                ..Default::default()
            },
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("calibrated at EM gain 300"), "{e}");
    }
}
