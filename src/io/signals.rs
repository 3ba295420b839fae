//! Stopping on SIGINT and SIGTERM (Ctrl-C, a service manager): a flag the work polls, so
//! what is under way finishes and is kept.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use signal_hook::consts::{SIGINT, SIGTERM};

/// A flag SIGINT and SIGTERM set. With `twice_exits`, a second signal (the flag already
/// set) ends the process at once with exit code 130, for whoever will not wait.
pub fn stop_flag(twice_exits: bool) -> std::io::Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [SIGINT, SIGTERM] {
        // Registered first: it must see the flag before this signal sets it.
        if twice_exits {
            signal_hook::flag::register_conditional_shutdown(sig, 130, stop.clone())?;
        }
        signal_hook::flag::register(sig, stop.clone())?;
    }
    Ok(stop)
}
