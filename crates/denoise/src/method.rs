//! What a user picks: the denoising methods, the output's units, and a model argument with its
//! self-ensemble size (`MODEL@K`).

use emccd_nn::{Classical, Error, Inputs, Result};
use emccd_profile::CameraProfile;

/// A denoising method.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Method {
    /// A classical estimate refined by a network (bundled model `hybrid`): the network sees the
    /// frame, its noise level and the estimate its model file names (one BM3D + GAT pass, or
    /// iterative BM3D), and corrects it; it starts from that estimate's quality and learns to
    /// improve on it (+0.09 dB over BM3D on the low-light suite). The estimate's time plus the
    /// network's.
    Hybrid,
    /// Iterative BM3D (`ivst`) and a network (bundled model `lowlight`), averaged pixel by
    /// pixel: their errors are partly independent, so the average is better than either at
    /// every light level of the low-light suite (docs/results.md). Their two times.
    Blend,
    /// The network alone: bundled model `lowlight` (the best network), or `--model default` /
    /// `microscopy` / a file. The fastest.
    #[cfg_attr(feature = "clap", value(alias = "network"))]
    Net,
    /// BM3D after the generalized Anscombe transform (gain = the profile's slope, Gaussian σ =
    /// its read noise), with the exact unbiased inverse.
    Bm3d,
    /// BM3D with iterative variance stabilization (Azzari & Foi 2016): up to four BM3D passes,
    /// each on the data mixed with the previous estimate and, below a few photoelectrons per
    /// pixel, summed over 2×2–4×4 bins; the passes are chosen from the frame's light level.
    /// Better than `bm3d` below about 8 e⁻ per pixel (4 counts), the same above; up to about
    /// 2.3× its time.
    Ivst,
    /// A movie's frame from the frames around it (`--window K`: the K frames before and after it,
    /// 12 by default, or the 3 nearest each side where the frame's own data, held out of both,
    /// finds them clearly better): each neighbour registered and resampled to a fraction of a
    /// pixel, blocks tracked along the motion (the scene's, and each block's own move) are averaged
    /// into a motion-compensated mean, brought to the frame's brightness (bleaching), which
    /// iterative BM3D denoises at a mean's noise; where the neighbours do not match (motion it
    /// cannot follow, a blink, a scene cut) each pixel falls back to the frame's own estimate
    /// (`ivst` below one count per pixel, one BM3D pass from there), as does a single frame. About
    /// 2.2–2.6 times BM3D's time.
    Temporal,
    /// A movie's frame by a temporal network (bundled model `movie`): the frame and the two
    /// before and after it in, the frame out. Trained on movies synthesized with the exact
    /// noise chain and every kind of motion the movie suite has (drift, rotation, deformation,
    /// jitter, diffusing and blinking spots, bleaching, cuts), so it learns where the
    /// neighbours match the frame and where they do not. It is shown the frame's scene (the
    /// classical method's tracking and the whole frames' correlation end it at a cut) brought
    /// to the frame's brightness
    /// (bleaching), the frames beyond the scene or the movie mirrored about the frame; a lone
    /// frame is shown in every slot. The fastest temporal method.
    #[cfg_attr(feature = "clap", value(name = "temporal-net"))]
    TemporalNet,
    /// No denoising: blooming and the fixed pattern removed and the units converted, as every
    /// method does first (the preprocessed photo-signal, for one's own analysis).
    None,
}

/// The method run with neither a method nor a model: the most accurate one shipped on the
/// low-light suite (docs/results.md): `blend` (iterative BM3D and the `lowlight` network,
/// averaged) is above `ivst`, the network alone and plain BM3D at every light level there (its
/// weight, ½, was chosen on the separate validation camera).
pub const DEFAULT_METHOD: Method = Method::Blend;

/// The method a recording of more than one frame runs when no method or model is asked: each
/// frame from its neighbours too. On the movie suite's validation camera it is above `blend`
/// on every kind of motion and light level (docs/results.md); a single frame still runs
/// [`DEFAULT_METHOD`].
pub const DEFAULT_MOVIE_METHOD: Method = Method::Temporal;

impl Method {
    /// Every method.
    pub const ALL: [Method; 8] = [
        Method::Hybrid,
        Method::Blend,
        Method::Net,
        Method::Bm3d,
        Method::Ivst,
        Method::Temporal,
        Method::TemporalNet,
        Method::None,
    ];

    /// The classical single-frame estimate this method is, if it is one (`temporal`'s own, on
    /// a frame without neighbours, is [`emccd_classical::temporal::single`]).
    pub fn classical(self) -> Option<Classical> {
        match self {
            Method::Bm3d => Some(Classical::Bm3d),
            Method::Ivst => Some(Classical::Ivst),
            Method::Hybrid
            | Method::Blend
            | Method::Net
            | Method::Temporal
            | Method::TemporalNet
            | Method::None => None,
        }
    }

    /// The name `--method` takes.
    pub fn name(self) -> &'static str {
        match self {
            Method::Hybrid => "hybrid",
            Method::Blend => "blend",
            Method::Net => "net",
            Method::Bm3d => "bm3d",
            Method::Ivst => "ivst",
            Method::Temporal => "temporal",
            Method::TemporalNet => "temporal-net",
            Method::None => "none",
        }
    }

    /// Whether the method estimates a frame from its neighbours too (and so takes a window).
    pub fn temporal(self) -> bool {
        matches!(self, Method::Temporal | Method::TemporalNet)
    }

    /// Whether the method runs a network (and so takes a model).
    pub fn uses_model(self) -> bool {
        matches!(
            self,
            Method::Hybrid | Method::Blend | Method::Net | Method::TemporalNet
        )
    }

    /// What the method's network is given (for the methods that run one).
    pub fn inputs(self) -> Inputs {
        match self {
            Method::Hybrid => Inputs::Hybrid,
            Method::TemporalNet => Inputs::Movie,
            _ => Inputs::Noisy,
        }
    }

    /// The bundled model the method runs when none is named.
    pub fn default_model(self) -> &'static str {
        match self {
            Method::Hybrid => "hybrid",
            Method::TemporalNet => "movie",
            _ => "lowlight",
        }
    }
}

impl std::str::FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Method> {
        let s = if s == "network" { "net" } else { s };
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                Error::Model(format!(
                    "method {s:?}: the methods are {}",
                    Method::ALL.map(Method::name).join(", ")
                ))
            })
    }
}

/// The units denoised frames are written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
pub enum Units {
    /// DN above bias (the photo-signal, blooming and fixed pattern removed).
    #[default]
    Dn,
    /// Photo-electrons: DN / K with K = s/2 (the EM register's f² = 2).
    Electrons,
}

impl Units {
    /// The name `--units` takes.
    pub fn name(self) -> &'static str {
        match self {
            Units::Dn => "dn",
            Units::Electrons => "electrons",
        }
    }

    /// What the values are, in words (for provenance and reports).
    pub fn describe(self) -> &'static str {
        match self {
            Units::Dn => "DN above bias",
            Units::Electrons => "photoelectrons",
        }
    }

    /// The factor from DN above bias to these units through `profile`.
    pub fn factor(self, profile: &CameraProfile) -> Result<f32> {
        Ok(match self {
            Units::Dn => 1.0,
            Units::Electrons => (1.0 / profile.dn_per_electron()?) as f32,
        })
    }
}

impl std::str::FromStr for Units {
    type Err = Error;
    fn from_str(s: &str) -> Result<Units> {
        [Units::Dn, Units::Electrons]
            .into_iter()
            .find(|u| u.name() == s)
            .ok_or_else(|| {
                Error::Data(format!(
                    "units {s:?}: the units are \"dn\" (DN above bias) or \"electrons\""
                ))
            })
    }
}

/// The self-ensemble sizes allowed: up to the eight flips and transposes of a frame.
const ENSEMBLES: [usize; 4] = [1, 2, 4, 8];

/// A self-ensemble size (orientations a network is averaged over) as a flag gives it: 1, 2, 4
/// or 8.
pub fn ensemble_size(k: &str) -> Result<usize> {
    check_ensemble(k.parse::<usize>().unwrap_or(0))
}

/// `k` if it is a self-ensemble size (1, 2, 4 or 8 orientations).
pub fn check_ensemble(k: usize) -> Result<usize> {
    if ENSEMBLES.contains(&k) {
        Ok(k)
    } else {
        Err(Error::Model(
            "the self-ensemble is 1, 2, 4 or 8 orientations".into(),
        ))
    }
}

/// A model argument with an optional self-ensemble suffix: `microscopy@8` is the bundled
/// `microscopy` model averaged over 8 orientations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModelSpec<'a> {
    /// The model: a bundled name or a file.
    pub model: &'a str,
    /// Orientations averaged (1 without a suffix).
    pub ensemble: usize,
}

impl<'a> ModelSpec<'a> {
    /// Splits `MODEL[@K]`.
    pub fn parse(arg: &'a str) -> Result<ModelSpec<'a>> {
        match arg.rsplit_once('@') {
            Some((model, k)) => Ok(ModelSpec {
                model,
                ensemble: ensemble_size(k)
                    .map_err(|e| Error::Model(format!("{arg}: after `@`, {e}")))?,
            }),
            None => Ok(ModelSpec {
                model: arg,
                ensemble: 1,
            }),
        }
    }
}
