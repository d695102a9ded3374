//! (stage to be written: module docs give what, algorithm, parameters, reference, complexity)

use serde::{Deserialize, Serialize};

/// Parameters of this stage (JSON object `vectorize` in the job parameters).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Params {}

impl Params {
    /// Check every field; the message names the offending parameter.
    pub fn validate(&self) -> Result<(), String> {
        Ok(())
    }
}
