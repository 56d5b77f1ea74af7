//! Plant blocks (DESIGN.md "Blocks"). In progress.
