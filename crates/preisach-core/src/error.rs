//! The one error type of the core. Every message names the argument and the problem,
//! so the Python layer can pass it through unchanged as a `ValueError`.

/// Errors raised by the core. Messages are complete sentences fit for a user.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PreisachError {
    /// A bad argument: `name` is the argument, `problem` says what is wrong with it.
    #[error("{name}: {problem}")]
    Invalid { name: String, problem: String },
    /// A serialized model, state or chain that cannot be read back.
    #[error("corrupt {what}: {problem}")]
    Corrupt { what: String, problem: String },
    /// The numerical solver failed to reach a solution.
    #[error("solver failed: {0}")]
    Solver(String),
}

/// Result alias used throughout the core.
pub type Result<T> = std::result::Result<T, PreisachError>;

impl PreisachError {
    /// Shorthand for [`PreisachError::Invalid`].
    pub fn invalid(name: impl Into<String>, problem: impl Into<String>) -> Self {
        PreisachError::Invalid { name: name.into(), problem: problem.into() }
    }
    /// Shorthand for [`PreisachError::Corrupt`].
    pub fn corrupt(what: impl Into<String>, problem: impl Into<String>) -> Self {
        PreisachError::Corrupt { what: what.into(), problem: problem.into() }
    }
}

/// Check that every value of `xs` is finite; the error names the first bad index.
pub fn check_finite(name: &str, xs: &[f64]) -> Result<()> {
    // A value is NaN or infinite exactly when its exponent bits are all ones: an integer
    // OR over a block (vectorized, no branch per sample) finds a bad block; only then is
    // the index searched.
    const EXP: u64 = 0x7ff0_0000_0000_0000;
    let all_finite = xs.chunks(1024).all(|c| c.iter().fold(0u64, |a, &x| a | ((x.to_bits() & EXP) == EXP) as u64) == 0);
    if all_finite {
        return Ok(());
    }
    if let Some(i) = xs.iter().position(|x| !x.is_finite()) {
        let what = if xs[i].is_nan() { "NaN" } else { "inf" };
        return Err(PreisachError::invalid(name, format!("{what} at index {i}")));
    }
    Ok(())
}

/// Check that `xs` is non-empty and finite.
pub fn check_signal(name: &str, xs: &[f64]) -> Result<()> {
    if xs.is_empty() {
        return Err(PreisachError::invalid(name, "empty array"));
    }
    check_finite(name, xs)
}

/// Check that a scalar parameter is finite.
pub fn check_scalar(name: &str, x: f64) -> Result<()> {
    if !x.is_finite() {
        return Err(PreisachError::invalid(name, format!("must be finite, got {x}")));
    }
    Ok(())
}
