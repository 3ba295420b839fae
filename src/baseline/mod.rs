//! Whole-cube baselines: the paper's method and brute force.
