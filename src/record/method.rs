//! The method and the field model a run used, by the names `summary.json` and the command
//! line give them: records below the estimator, which re-exports them.

/// Which estimator to run; `summary.json`'s `method` by its name.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// The streaming estimator (default).
    Filmscope,
    /// Kobayashi et al.'s method, faithfully: eq. 12 from pairs of angles, eqs. 13-14.
    Paper,
    /// Least squares over an (n, d) grid: the paper's O(m N^2) baseline.
    Brute,
}

impl Method {
    /// Parses `filmscope`, `paper` or `brute`.
    pub fn from_name(name: &str) -> Option<Self> {
        match name {
            "filmscope" => Some(Self::Filmscope),
            "paper" => Some(Self::Paper),
            "brute" => Some(Self::Brute),
            _ => None,
        }
    }

    /// The method's name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Filmscope => "filmscope",
            Self::Paper => "paper",
            Self::Brute => "brute",
        }
    }
}

/// The field model a run used; `summary.json`'s `field_model` by its name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FieldModel {
    /// One incidence angle per frame: the stage angle.
    Narrow,
    /// The angle varies with the column: strips of columns, each with its own angles.
    Wide,
}

impl FieldModel {
    /// The model's name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Narrow => "narrow",
            Self::Wide => "wide",
        }
    }
}
