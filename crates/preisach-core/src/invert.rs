//! Inversion (seed §4): closest match, interpolation, continuous inverse. In progress.
