//! Ray hashers (seed 000 §3.2.3, figs 3.8-3.9): one sort key per ray.
