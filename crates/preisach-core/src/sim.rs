//! The 100 kHz sample loop. In progress.
