//! Which of the twin's two formulas a search fits.

/// What a search is for, for progress reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// The amplitude model.
    Amplitude,
    /// The phase model.
    Phase,
}
