//! Ray-space hierarchy traversers (seed 000 §3.2.8).
