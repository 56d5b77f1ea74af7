//! placeholder until identification lands
