//! Ray-space hierarchy builders (seed 000 §3.2.7).
