//! The integration tests, one module per file beside this one, built as one test binary
//! (`cargo test --release --test integration`; a file's tests by its name, e.g.
//! `cargo test --release --test integration rig::`). The long line soak is a binary of its
//! own (`tests/soak.rs`).

mod common;

mod accuracy;
mod appearance;
mod baselines;
mod capture_toml;
mod cli_estimate;
mod colour_reference;
mod envi_io;
mod equivalence;
mod external_capture;
mod field_of_view;
mod gltf_export;
mod hardening;
mod inspect;
mod inspect_status;
mod layout;
mod line_modbus;
mod line_mqtt;
mod material_files;
mod optics_tmm;
mod peers;
mod png_preview;
mod random_eval;
mod real_measurements;
mod reliability;
mod report_browser;
mod rig;
mod simulate_capture;
mod stability;
