//! File formats: ENVI cubes and capture descriptions.
