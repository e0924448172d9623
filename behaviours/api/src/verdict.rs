//! How a behaviour ends: a [`Verdict`] with a summary line and named figures.

/// How a behaviour judged its run.
#[derive(Clone, Debug, PartialEq)]
pub struct Verdict {
    /// Whether its success criteria held.
    pub success: bool,
    /// One line for the report.
    pub summary: String,
    /// Named figures for the report.
    pub metrics: Vec<(String, f64)>,
}

impl Verdict {
    /// A success or a failure, as `success` says.
    pub fn new(success: bool, summary: impl Into<String>) -> Self {
        Self {
            success,
            summary: summary.into(),
            metrics: Vec::new(),
        }
    }

    /// A success.
    pub fn success(summary: impl Into<String>) -> Self {
        Self {
            success: true,
            summary: summary.into(),
            metrics: Vec::new(),
        }
    }

    /// A failure.
    pub fn failure(summary: impl Into<String>) -> Self {
        Self {
            success: false,
            summary: summary.into(),
            metrics: Vec::new(),
        }
    }

    /// Adds a figure.
    pub fn with(mut self, name: impl Into<String>, value: f64) -> Self {
        self.metrics.push((name.into(), value));
        self
    }
}
