//! Every pipeline parameter, with its documented default, in one place.
//!
//! `Params` is what users send (JSON, every field optional, one object per stage);
//! [`Params::validate`] turns it into [`ValidParams`] or says which parameter is wrong,
//! before any point is read. Each stage declares its own `Params` next to its algorithm,
//! with the defaults and their sources in its module docs:
//!
//! | object | stage | module |
//! |---|---|---|
//! | `pavement` | road surface from slices (Yao 2019) or scan lines (Yao 2021) | [`super::pavement`], [`super::pavement_scanline`] |
//! | `rasterize` | background normalisation + IDW raster | [`super::rasterize`] |
//! | `threshold` | Bradley–Roth + cleanup + points back | [`super::threshold`] |
//! | `cluster`, `classify`, `vectorize` | clusters, classes, outlines and lane lines | [`super::cluster`], [`super::classify`], [`super::vectorize`] |
//! | `learned` | the learned classifier for undecided candidates (`mode`: auto/on/off) | [`super::learned::refine`] |
//! | `chunk` | chunking along the trajectory for bounded memory | [`super::chunk`] |
//!
//! `serde_json::to_string_pretty(&Params::default())` prints the whole default set.

use super::{chunk, classify, cluster, learned, pavement, rasterize, threshold, vectorize};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {
    pub pavement: pavement::Params,
    pub rasterize: rasterize::Params,
    pub threshold: threshold::Params,
    pub cluster: cluster::Params,
    pub classify: classify::Params,
    pub vectorize: vectorize::Params,
    pub learned: learned::Params,
    pub chunk: chunk::Params,
}

/// Parameters that passed validation.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(transparent)]
pub struct ValidParams(Params);

impl std::ops::Deref for ValidParams {
    type Target = Params;
    fn deref(&self) -> &Params {
        &self.0
    }
}

impl Params {
    /// Parse a JSON parameter object (unknown fields are errors).
    pub fn from_json(text: &str) -> Result<Params, String> {
        serde_json::from_str(text).map_err(|e| e.to_string())
    }

    /// Check every stage's parameters and the constraints between stages; the error names
    /// the parameter as `stage.field: problem`.
    pub fn validate(self) -> Result<ValidParams, String> {
        let checks: [(&str, Result<(), String>); 8] = [
            ("pavement", self.pavement.validate()),
            ("rasterize", self.rasterize.validate()),
            ("threshold", self.threshold.validate()),
            ("cluster", self.cluster.validate()),
            ("classify", self.classify.validate()),
            ("vectorize", self.vectorize.validate()),
            ("learned", self.learned.validate()),
            ("chunk", self.chunk.validate()),
        ];
        for (stage, r) in checks {
            r.map_err(|e| format!("{stage}.{e}"))?;
        }
        let need = chunk::required_overlap_m(&self);
        if self.chunk.overlap_m > 0.0 && self.chunk.overlap_m < need {
            return Err(format!(
                "chunk.overlap_m: must be 0 (automatic) or at least {need:.2} m for these stage parameters, got {}",
                self.chunk.overlap_m
            ));
        }
        if self.chunk.length_m < self.pavement.slice_length_m {
            return Err(format!(
                "chunk.length_m: must be at least pavement.slice_length_m ({}), got {}",
                self.pavement.slice_length_m, self.chunk.length_m
            ));
        }
        Ok(ValidParams(self))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_round_trip_through_json() {
        let p = Params::default();
        let text = serde_json::to_string(&p).unwrap();
        assert_eq!(Params::from_json(&text).unwrap(), p);
        p.validate().unwrap();
        assert_eq!(Params::from_json("{}").unwrap(), Params::default());
    }

    #[test]
    fn errors_name_the_parameter() {
        let e = Params::from_json(r#"{"rasterize": {"cell_size_m": 0}}"#)
            .unwrap()
            .validate()
            .unwrap_err();
        assert!(e.starts_with("rasterize.cell_size_m"), "{e}");
        let e = Params::from_json(r#"{"pavement": {"scan_lines": {"curb_height_m": -1}}}"#)
            .unwrap()
            .validate()
            .unwrap_err();
        assert!(e.starts_with("pavement.scan_lines.curb_height_m"), "{e}");
        let e = Params::from_json(r#"{"chunk": {"overlap_m": 1}}"#)
            .unwrap()
            .validate()
            .unwrap_err();
        assert!(e.starts_with("chunk.overlap_m"), "{e}");
        let e = Params::from_json(r#"{"threshold": {"nonsense": 1}}"#).unwrap_err();
        assert!(e.contains("nonsense"), "{e}");
        let e = Params::from_json(r#"{"learned": {"decisive_confidence": 2}}"#)
            .unwrap()
            .validate()
            .unwrap_err();
        assert!(e.starts_with("learned.decisive_confidence"), "{e}");
        let p = Params::from_json(r#"{"learned": {"mode": "off"}}"#).unwrap();
        assert_eq!(p.learned.mode, learned::refine::Mode::Off);
        // NaN cannot be written in JSON; a string where a number belongs is a parse error.
        assert!(Params::from_json(r#"{"rasterize": {"radius_m": "x"}}"#).is_err());
    }
}
