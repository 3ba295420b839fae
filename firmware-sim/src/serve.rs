//! The simulated rig behind real transports: each serial device on its own pty (the host
//! opens the printed path exactly as it would `/dev/ttyUSB0`) and the camera on a TCP port
//! of 127.0.0.1 or a Unix socket. Device time runs `speed` times faster than the wall.

use std::io::{self, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use filmscope_core::proto::fscl::{self, Decoded};
use serialport::{SerialPort, TTYPort};

use crate::camera::SoftwareCamera;
use crate::camlink::{After, CameraFaults, CameraFirmware};
use crate::clock::ScaledClock;
use crate::kurios::KuriosFilter;
use crate::serial::{lock, LineFirmware, SerialDevice, SerialFaults, Shared};
use crate::wheel::SxWheelFirmware;
use crate::world::World;
use crate::zaber::{MotionFault, ZaberStage};
use crate::Scene;

/// Where the camera listens.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum CameraEndpoint {
    /// A TCP address on 127.0.0.1.
    Tcp(String),
    /// A Unix socket path.
    Unix(PathBuf),
}

impl std::fmt::Display for CameraEndpoint {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Tcp(a) => write!(f, "tcp:{a}"),
            Self::Unix(p) => write!(f, "unix:{}", p.display()),
        }
    }
}

/// How to build the simulated rig.
#[derive(Clone, Debug)]
pub struct RigOptions {
    /// The scene the camera looks at.
    pub scene: Scene,
    /// Device time per wall time.
    pub speed: f64,
    /// Stage microsteps per degree.
    pub steps_per_deg: f64,
    /// Stage travel, degrees.
    pub stage_limits_deg: [f64; 2],
    /// Stage faults.
    pub stage_faults: SerialFaults,
    /// A stage motion fault.
    pub motion_fault: Option<MotionFault>,
    /// Filter faults.
    pub filter_faults: SerialFaults,
    /// Camera faults.
    pub camera_faults: CameraFaults,
    /// `Some(address)`: the stage answers as the device at this address.
    pub stage_reply_address: Option<u8>,
    /// `Some(path)`: the camera on a Unix socket instead of TCP.
    pub unix_socket: Option<PathBuf>,
}

impl RigOptions {
    /// Defaults around `scene`: a 4266.67 step/degree stage with 0-90 degree travel, no
    /// faults, camera on TCP, device time 50 times the wall's.
    pub fn new(scene: Scene) -> Self {
        Self {
            scene,
            speed: 50.0,
            steps_per_deg: 4_266.666_666_666_667,
            stage_limits_deg: [0.0, 90.0],
            stage_faults: SerialFaults::default(),
            motion_fault: None,
            filter_faults: SerialFaults::default(),
            camera_faults: CameraFaults::default(),
            stage_reply_address: None,
            unix_socket: None,
        }
    }
}

/// A running simulated rig. Dropping it stops the devices.
pub struct SimRig {
    /// The stage's pty path.
    pub stage_port: String,
    /// The filter's pty path.
    pub filter_port: String,
    /// The camera's endpoint.
    pub camera: CameraEndpoint,
    /// The stage (transcript, state).
    pub stage: Shared<ZaberStage>,
    /// The filter (transcript, state).
    pub filter: Shared<KuriosFilter>,
    /// The filter wheel (HID has no pty: the host reaches it in process).
    pub wheel: Arc<Mutex<SxWheelFirmware>>,
    /// The shared physical state.
    pub world: World,
    /// The device clock.
    pub clock: ScaledClock,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

impl Drop for SimRig {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

fn serve_pty<F: LineFirmware + 'static>(
    device: Shared<F>,
    clock: ScaledClock,
    stop: Arc<AtomicBool>,
) -> io::Result<(String, JoinHandle<()>)> {
    let (mut master, slave) = TTYPort::pair().map_err(io::Error::from)?;
    let path = slave
        .name()
        .ok_or_else(|| io::Error::other("the pty has no name"))?;
    master
        .set_timeout(Duration::from_millis(2))
        .map_err(io::Error::from)?;
    let handle = std::thread::spawn(move || {
        // The slave end stays open while the device lives, so the master never sees a hang-up
        // before the host connects; both close when the device disappears.
        let _slave = slave;
        let mut buf = [0u8; 512];
        while !stop.load(Ordering::SeqCst) {
            match master.read(&mut buf) {
                Ok(n) if n > 0 => lock(&device).receive(&buf[..n], clock.now_us()),
                Ok(_) => {}
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
                Err(_) => std::thread::sleep(Duration::from_millis(2)),
            }
            loop {
                let out = {
                    let mut dev = lock(&device);
                    if dev.is_gone() {
                        return;
                    }
                    dev.transmit(4096)
                };
                if out.is_empty() || master.write_all(&out).is_err() {
                    break;
                }
                let _ = master.flush();
            }
        }
    });
    Ok((path, handle))
}

fn serve_camera<S: Read + Write>(
    stream: &mut S,
    firmware: &mut CameraFirmware,
    clock: ScaledClock,
    stop: &AtomicBool,
) -> After {
    let mut buf: Vec<u8> = Vec::new();
    let mut chunk = [0u8; 4096];
    // Bytes to send again while the host is silent (fault injection), and when next.
    let mut repeat: Option<(Vec<u8>, Duration, std::time::Instant)> = None;
    while !stop.load(Ordering::SeqCst) {
        match stream.read(&mut chunk) {
            Ok(0) => return After::Continue, // the host hung up
            Ok(n) => {
                repeat = None;
                buf.extend_from_slice(&chunk[..n]);
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::WouldBlock | io::ErrorKind::TimedOut
                ) =>
            {
                if let Some((bytes, every, next)) = repeat.as_mut() {
                    if std::time::Instant::now() >= *next {
                        if stream.write_all(bytes).is_err() {
                            return After::Continue;
                        }
                        *next = std::time::Instant::now() + *every;
                    }
                }
                continue;
            }
            Err(_) => return After::Continue,
        }
        loop {
            if buf.is_empty() {
                break;
            }
            match fscl::decode(&buf, 1024) {
                Decoded::Message {
                    header,
                    payload,
                    consumed,
                } => {
                    let (bytes, after) = firmware.answer(header, payload, clock.now_us());
                    buf.drain(..consumed);
                    match after {
                        After::Vanish => return After::Vanish,
                        After::Continue => {
                            if stream.write_all(&bytes).is_err() {
                                return After::Continue;
                            }
                        }
                        After::Repeat(every) => {
                            if stream.write_all(&bytes).is_err() {
                                return After::Continue;
                            }
                            repeat = Some((bytes, every, std::time::Instant::now() + every));
                        }
                        After::Trickle(gap) => {
                            for b in bytes {
                                if stop.load(Ordering::SeqCst) {
                                    return After::Continue;
                                }
                                if stream
                                    .write_all(&[b])
                                    .and_then(|()| stream.flush())
                                    .is_err()
                                {
                                    return After::Continue;
                                }
                                std::thread::sleep(gap);
                            }
                        }
                    }
                }
                Decoded::Incomplete { .. } => break,
                Decoded::BadCrc { consumed } => {
                    buf.drain(..consumed);
                }
                Decoded::Garbage { skip } => {
                    buf.drain(..skip);
                }
            }
        }
    }
    After::Continue
}

enum Listener {
    Tcp(TcpListener),
    Unix(UnixListener, PathBuf),
}

fn camera_thread(
    listener: Listener,
    mut firmware: CameraFirmware,
    clock: ScaledClock,
    stop: Arc<AtomicBool>,
) -> JoinHandle<()> {
    std::thread::spawn(move || {
        let tick = Some(Duration::from_millis(20));
        while !stop.load(Ordering::SeqCst) {
            let after = match &listener {
                Listener::Tcp(l) => match l.accept() {
                    Ok((mut s, _)) => {
                        let _ = s.set_nonblocking(false);
                        let _ = s.set_read_timeout(tick);
                        let _ = s.set_nodelay(true);
                        let after = serve_camera(&mut s, &mut firmware, clock, &stop);
                        let _ = s.shutdown(std::net::Shutdown::Both);
                        after
                    }
                    Err(_) => {
                        std::thread::sleep(Duration::from_millis(5));
                        After::Continue
                    }
                },
                Listener::Unix(l, _) => match l.accept() {
                    Ok((mut s, _)) => {
                        let _ = s.set_nonblocking(false);
                        let _ = s.set_read_timeout(tick);
                        let after = serve_camera(&mut s, &mut firmware, clock, &stop);
                        let _ = s.shutdown(std::net::Shutdown::Both);
                        after
                    }
                    Err(_) => {
                        std::thread::sleep(Duration::from_millis(5));
                        After::Continue
                    }
                },
            };
            if after == After::Vanish {
                break;
            }
        }
        if let Listener::Unix(_, path) = &listener {
            let _ = std::fs::remove_file(path);
        }
    })
}

/// Starts the simulated rig: stage and filter on ptys, the camera on a socket.
pub fn start(options: RigOptions) -> io::Result<SimRig> {
    let clock = ScaledClock::new(options.speed);
    let stop = Arc::new(AtomicBool::new(false));
    let world = World::new();
    let spd = options.steps_per_deg;
    let limits = [
        (options.stage_limits_deg[0] * spd).round() as i64,
        (options.stage_limits_deg[1] * spd).round() as i64,
    ];
    let mut stage_fw = ZaberStage::new(1, spd, limits, 20.0, world.clone());
    if let Some(f) = options.motion_fault {
        stage_fw = stage_fw.with_fault(f);
    }
    if let Some(a) = options.stage_reply_address {
        stage_fw = stage_fw.with_reply_address(a);
    }
    let stage = Arc::new(Mutex::new(SerialDevice::new(
        stage_fw,
        options.stage_faults,
    )));
    let filter = Arc::new(Mutex::new(SerialDevice::new(
        KuriosFilter::new(300_000, world.clone()),
        options.filter_faults,
    )));
    let mut threads = Vec::new();
    let (stage_port, t) = serve_pty(stage.clone(), clock, stop.clone())?;
    threads.push(t);
    let (filter_port, t) = serve_pty(filter.clone(), clock, stop.clone())?;
    threads.push(t);
    let camera_fw = CameraFirmware::new(
        SoftwareCamera::new(options.scene),
        world.clone(),
        options.camera_faults,
    );
    let (listener, camera) = match options.unix_socket {
        Some(path) => {
            let _ = std::fs::remove_file(&path);
            let l = UnixListener::bind(&path)?;
            l.set_nonblocking(true)?;
            (Listener::Unix(l, path.clone()), CameraEndpoint::Unix(path))
        }
        None => {
            let l = TcpListener::bind("127.0.0.1:0")?;
            l.set_nonblocking(true)?;
            let addr = l.local_addr()?.to_string();
            (Listener::Tcp(l), CameraEndpoint::Tcp(addr))
        }
    };
    threads.push(camera_thread(listener, camera_fw, clock, stop.clone()));
    Ok(SimRig {
        stage_port,
        filter_port,
        camera,
        stage,
        filter,
        wheel: Arc::new(Mutex::new(SxWheelFirmware::new(5, 200_000))),
        world,
        clock,
        stop,
        threads,
    })
}

/// Connects to a camera endpoint as the host would (for tests of the server alone).
pub fn connect_tcp(addr: &str) -> io::Result<TcpStream> {
    TcpStream::connect(addr)
}

/// Connects to a Unix-socket camera endpoint.
pub fn connect_unix(path: &std::path::Path) -> io::Result<UnixStream> {
    UnixStream::connect(path)
}
