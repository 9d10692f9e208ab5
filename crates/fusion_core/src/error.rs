//! Error type shared by every fusion_core kernel.

/// Everything that can go wrong in fusion_core. Bad input is always an
/// `InvalidArgument` naming the offending argument; never a panic.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FusionError {
    /// An argument failed validation; `name` is the argument's name as the caller knows it.
    #[error("{name}: {reason}")]
    InvalidArgument { name: &'static str, reason: String },
    /// The cloud holds nothing that could be localized as an insulator.
    #[error("no insulator: {0}")]
    NoInsulator(String),
    /// The bounded method cannot tell which line in the box is the insulator: another,
    /// larger line fits the insulator's known length better than the one fitted
    /// (`crate::localize::bounded::ambiguity`). Refused rather than guessed.
    #[error("ambiguous: {0}")]
    Ambiguous(String),
}

/// Result alias used throughout fusion_core.
pub type Result<T> = std::result::Result<T, FusionError>;

/// Shorthand for building an [`FusionError::InvalidArgument`].
pub(crate) fn invalid(name: &'static str, reason: impl Into<String>) -> FusionError {
    FusionError::InvalidArgument { name, reason: reason.into() }
}

/// Checks that `value` is finite and strictly positive.
pub(crate) fn check_positive(name: &'static str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(invalid(name, format!("must be finite and > 0, got {value}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_the_argument() {
        let e = invalid("eps", "must be > 0");
        assert_eq!(e.to_string(), "eps: must be > 0");
        assert_eq!(FusionError::NoInsulator("empty".into()).to_string(), "no insulator: empty");
        assert!(check_positive("eps", 0.0).is_err());
        assert!(check_positive("eps", f64::NAN).is_err());
        assert!(check_positive("eps", f64::INFINITY).is_err());
        assert!(check_positive("eps", 1e-9).is_ok());
    }
}
