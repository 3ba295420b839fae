//! On a production line: `filmscope inspect` measures sample after sample against a recipe.
//!
//! - [`recipe`]: the recipe file (tolerances, regions, index carrying, SPC, retention, MQTT,
//!   status page).
//! - [`verdict`]: PASS/FAIL with every reason, the out-of-tolerance mask and its regions.
//! - [`spc`]: rolling history, individuals/moving-range limits, Cpk/Ppk, Nelson rules 1-4.
//! - [`stream`]: `results.jsonl` (fsynced, rotated, rebuilt after a crash) and MQTT (TLS,
//!   topics per kind, every record kept until the broker acknowledges it).
//! - [`status`]: the live status page, JSON API and Prometheus metrics.
//! - [`tls`]: the MQTT client's TLS configuration from the recipe's PEM files.
//! - [`plc`]: the Modbus TCP server a PLC reads the verdict from and triggers samples with.
//! - [`listen`]: the thread and runtime each of those servers runs on.
//! - [`retention`]: which raw sweeps are kept, uint16 references, the disk budget.
//! - [`results`]: the results log as CSV (`filmscope results OUT --csv`).
//! - [`folder`]: the error naming a file of the folder that cannot be read or written.
//! - [`inspect`]: the loop that ties them to the rig and the estimator.

pub mod folder;
pub mod inspect;
pub mod listen;
pub mod plc;
pub mod recipe;
pub mod results;
pub mod retention;
pub mod spc;
pub mod status;
pub mod stream;
pub mod tls;
pub mod verdict;
