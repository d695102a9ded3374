//! Every pipeline parameter, with its documented default, in one place.
//!
//! `Params` is what users send (JSON, every field optional, one object per stage);
//! [`Params::validate`] turns it into [`ValidParams`] or says which parameter is wrong,
//! before any point is read. Each stage declares its own `Params` next to its algorithm.

use super::{classify, cluster, pavement, rasterize, threshold, vectorize};
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

    pub fn validate(self) -> Result<ValidParams, String> {
        let checks: [(&str, Result<(), String>); 6] = [
            ("pavement", self.pavement.validate()),
            ("rasterize", self.rasterize.validate()),
            ("threshold", self.threshold.validate()),
            ("cluster", self.cluster.validate()),
            ("classify", self.classify.validate()),
            ("vectorize", self.vectorize.validate()),
        ];
        for (stage, r) in checks {
            r.map_err(|e| format!("{stage}.{e}"))?;
        }
        Ok(ValidParams(self))
    }
}
