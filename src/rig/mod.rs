//! The rig: device drivers over real transports, below the estimator: the live sweep that
//! reads them is a source ([`crate::source::live`]), its use case a job
//! ([`crate::jobs::acquire`]).
//!
//! - [`error`]: [`RigError`], one line naming the port, with its [`ErrorKind`].
//! - [`line`](mod@line): line reading over any `Read + Write`.
//! - [`zaber`], [`kurios`]: serial drivers (generic over `Read + Write` and the clock).
//! - [`wheel`]: the Starlight Xpress HID wheel behind [`wheel::HidTransport`].
//! - [`camlink`]: the camera-link receiver (any byte stream).
//! - [`config`]: the rig file, `rig.toml`.
//! - [`sim`]: `firmware-sim` started for a rig file, and the rig opened on it.
//!
//! [`open`] connects to a rig described by `rig.toml` (or to `firmware-sim`, whose ports
//! look the same).
//!
//! [`ErrorKind`]: filmscope_core::hw::ErrorKind

pub mod camlink;
pub mod clock;
pub mod config;
pub mod error;
pub mod kurios;
pub mod line;
pub mod sim;
pub mod wheel;
pub mod zaber;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::os::unix::net::UnixStream;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use filmscope_core::hw::{
    ErrorKind, ErrorType, FilterWheel, FrameInfo, FrameRequest, LineCamera, LineEvent, Stage,
    TunableFilter,
};

pub use camlink::{CamLink, LinkStats};
pub use clock::SystemClock;
pub use config::RigConfig;
pub use error::RigError;
pub use kurios::{Kurios, KuriosConfig};
pub use wheel::{HidTransport, SxWheel};
pub use zaber::{Zaber, ZaberConfig};

/// A stage as the sweep uses it.
pub type DynStage = Box<dyn Stage<Error = RigError> + Send>;
/// A tunable filter as the sweep uses it.
pub type DynFilter = Box<dyn TunableFilter<Error = RigError> + Send>;
/// A filter wheel as the sweep uses it.
pub type DynWheel = Box<dyn FilterWheel<Error = RigError> + Send>;
/// A camera as the sweep uses it.
pub type DynCamera = Box<dyn LineCamera<Error = RigError> + Send>;

/// The devices of a rig.
pub struct Rig {
    /// Rotation stage.
    pub stage: DynStage,
    /// LCTF.
    pub filter: DynFilter,
    /// Filter wheel, if any.
    pub wheel: Option<DynWheel>,
    /// Camera.
    pub camera: DynCamera,
    /// Reads the camera link's fault counters (the camera is boxed).
    pub link_stats: Box<dyn Fn() -> LinkStats + Send>,
}

/// A camera whose link counters can be read while it is boxed.
struct CountedCamera<S> {
    link: CamLink<S>,
    stats: Arc<Mutex<LinkStats>>,
}

impl<S: Read + Write> CountedCamera<S> {
    fn publish(&self) {
        *self.stats.lock().unwrap_or_else(|p| p.into_inner()) = self.link.stats;
    }
}

impl<S: Read + Write> ErrorType for CountedCamera<S> {
    type Error = RigError;
}

impl<S: Read + Write> LineCamera for CountedCamera<S> {
    fn trigger(&mut self, request: FrameRequest) -> Result<FrameInfo, RigError> {
        let r = self.link.trigger(request);
        self.publish();
        r
    }

    fn read_line(&mut self, pixels: &mut [u16]) -> Result<LineEvent, RigError> {
        let r = self.link.read_line(pixels);
        self.publish();
        r
    }
}

/// Opens a serial port as the drivers need it.
pub fn open_serial(
    path: &str,
    baud: u32,
    timeout_ms: u64,
) -> Result<Box<dyn serialport::SerialPort>, RigError> {
    serialport::new(path, baud)
        .timeout(Duration::from_millis(timeout_ms))
        .open()
        .map_err(|e| RigError::new(path, ErrorKind::Disconnected, format!("cannot open: {e}")))
}

/// Connects to the camera at `address` (`tcp:HOST:PORT` or `unix:PATH`).
pub fn connect_camera(
    address: &str,
    width: u32,
    timeout_ms: u64,
) -> Result<(DynCamera, Arc<Mutex<LinkStats>>), RigError> {
    let timeout = Some(Duration::from_millis(timeout_ms.max(1)));
    let stats = Arc::new(Mutex::new(LinkStats::default()));
    let fail = |e: std::io::Error| {
        RigError::new(
            address,
            ErrorKind::Disconnected,
            format!("cannot connect: {e}"),
        )
    };
    let camera: DynCamera = if let Some(a) = address.strip_prefix("tcp:") {
        // The connect has its own deadline (a host that drops packets would hold it for
        // minutes): the link timeout per address the name resolves to.
        let connect_timeout = Duration::from_millis(timeout_ms.max(1));
        let mut last = None;
        let mut stream = None;
        for addr in std::net::ToSocketAddrs::to_socket_addrs(a).map_err(fail)? {
            match TcpStream::connect_timeout(&addr, connect_timeout) {
                Ok(s) => {
                    stream = Some(s);
                    break;
                }
                Err(e) => last = Some(e),
            }
        }
        let s = match (stream, last) {
            (Some(s), _) => s,
            (None, Some(e)) => return Err(fail(e)),
            (None, None) => {
                return Err(RigError::new(
                    address,
                    ErrorKind::Disconnected,
                    "cannot connect: the name resolves to no address",
                ))
            }
        };
        s.set_read_timeout(timeout).map_err(fail)?;
        let _ = s.set_nodelay(true);
        let mut link = CamLink::new(s, address, width);
        link.timeout_ms = timeout_ms.max(1);
        Box::new(CountedCamera {
            link,
            stats: stats.clone(),
        })
    } else if let Some(p) = address.strip_prefix("unix:") {
        let s = UnixStream::connect(p).map_err(fail)?;
        s.set_read_timeout(timeout).map_err(fail)?;
        let mut link = CamLink::new(s, address, width);
        link.timeout_ms = timeout_ms.max(1);
        Box::new(CountedCamera {
            link,
            stats: stats.clone(),
        })
    } else {
        return Err(RigError::new(
            address,
            ErrorKind::OutOfRange,
            "camera address must be tcp:HOST:PORT or unix:PATH",
        ));
    };
    Ok((camera, stats))
}

/// Opens every device of `config`; `wheel` is the wheel's transport when the rig has one
/// (the real one is [`wheel::HidapiTransport::open`]).
pub fn open(
    config: &RigConfig,
    wheel: Option<Box<dyn HidTransport + Send>>,
) -> Result<Rig, RigError> {
    open_with_clock(config, wheel, SystemClock::default())
}

/// [`open`] with the drivers' delays on `clock` (firmware-sim's clock when simulating, so
/// settle and motion times cost no wall time).
pub fn open_with_clock<C: filmscope_core::hw::Clock + Clone + Send + 'static>(
    config: &RigConfig,
    wheel: Option<Box<dyn HidTransport + Send>>,
    clock: C,
) -> Result<Rig, RigError> {
    let s = &config.stage;
    let stage_port = open_serial(&s.port, s.baud, s.timeout_ms)?;
    let stage = Zaber::new(
        stage_port,
        &s.port,
        clock.clone(),
        ZaberConfig {
            device: s.device,
            axis: s.axis,
            steps_per_deg: s.steps_per_deg,
            limits_deg: s.limits_deg,
            poll_us: s.poll_ms * 1000,
            // Each exchange: its attempts' read timeouts and as much again.
            exchange_timeout_ms: 2 * s.timeout_ms.max(1),
            ..ZaberConfig::default()
        },
    );
    let f = &config.filter;
    let filter_port = open_serial(&f.port, f.baud, f.timeout_ms)?;
    let filter = Kurios::new(
        filter_port,
        &f.port,
        clock.clone(),
        KuriosConfig {
            bandwidth: f.bandwidth,
            settle_us: f.settle_ms * 1000,
            exchange_timeout_ms: 2 * f.timeout_ms.max(1),
            ..KuriosConfig::default()
        },
    );
    let c = &config.camera;
    let (camera, stats) = connect_camera(&c.address, c.width, c.timeout_ms)?;
    let wheel: Option<DynWheel> = match (wheel, &config.wheel) {
        (Some(t), Some(_)) => Some(Box::new(SxWheel::new(t, "filter wheel", clock))),
        _ => None,
    };
    Ok(Rig {
        stage: Box::new(stage),
        filter: Box::new(filter),
        wheel,
        camera,
        link_stats: Box::new(move || *stats.lock().unwrap_or_else(|p| p.into_inner())),
    })
}

impl<T: HidTransport + ?Sized> HidTransport for Box<T> {
    fn write_report(&mut self, report: &[u8]) -> Result<(), RigError> {
        (**self).write_report(report)
    }

    fn read_report(&mut self, buf: &mut [u8], timeout_ms: i32) -> Result<usize, RigError> {
        (**self).read_report(buf, timeout_ms)
    }
}
