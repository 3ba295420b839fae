//! What a PLC reads and writes: a Modbus TCP server over a [`Snapshot`] of the line.
//!
//! The line hands the server a small `Copy` snapshot after each step (a sample judged, an
//! alarm raised, waiting for the trigger); the server only reads it, and a PLC can only set
//! the trigger coil, so nothing a Modbus client does reaches a measuring thread. The server
//! runs on a single-threaded tokio runtime on a thread of its own, at most
//! [`MAX_CONNECTIONS`] clients at once. An OPC UA server would attach the same way: another
//! reader of the same [`Snapshot`] and another writer of the same trigger.
//!
//! Register map (the same words on holding registers, function 03, and input registers,
//! function 04; addresses from 0; read-only):
//!
//! | address | content |
//! | --- | --- |
//! | 0 | heartbeat: +1 every second the server runs (wraps at 65535) |
//! | 1 | state: 0 starting, 1 waiting for the trigger coil, 2 measuring, 3 between samples, 4 stopped |
//! | 2-3 | counter of the last sample judged (u32, high word first) |
//! | 4 | verdict of the last sample: 0 none yet, 1 PASS, 2 FAIL |
//! | 5 | alarm bits: 0 run rule (last sample), 1 disk below its floor, 2 MQTT records not acknowledged, 3 device error (last attempt), 4 MQTT broker refused the login |
//! | 6-7 | mean thickness, nm (f32, IEEE 754, high word first; NaN: none) |
//! | 8-9 | smallest thickness, nm (f32) |
//! | 10-11 | largest thickness, nm (f32) |
//! | 12-13 | refractive index at 550 nm (f32) |
//! | 14-15 | valid fraction of the judged pixels, 0 to 1 (f32) |
//! | 16 | last error: 0 none, 1 device error, 2 disk full, 3 MQTT not acknowledged, 4 MQTT login refused |
//! | 17 | measurements started by the trigger coil (wraps at 65535) |
//!
//! Coil 0 (functions 01, 05, 15) is the trigger, "sample in place": a PLC sets it to 1;
//! `inspect` with `[modbus] trigger = "modbus"` waits for it and clears it when the
//! measurement starts.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU16, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio_modbus::{ExceptionCode, Request, Response};

use super::listen::ServerThread;

/// Modbus clients served at once; further ones are closed as they come.
pub const MAX_CONNECTIONS: usize = 16;
/// Words in the register map.
pub const REGISTERS: u16 = 18;
/// Coils: the trigger.
pub const COILS: u16 = 1;

/// What the line is doing, register 1.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LineState {
    /// Recovering the folder, connecting.
    #[default]
    Starting = 0,
    /// Waiting for the trigger coil.
    WaitingForTrigger = 1,
    /// A sweep under way.
    Measuring = 2,
    /// Between two free-running samples.
    Between = 3,
    /// Done; the process is closing.
    Stopped = 4,
}

/// Bits of register 5.
pub mod alarm_bit {
    /// A run rule fired on the last sample.
    pub const RUN_RULE: u16 = 1 << 0;
    /// The disk is below its free-space floor.
    pub const DISK_FLOOR: u16 = 1 << 1;
    /// Records wait for the broker's acknowledgement beyond `mqtt.ack_timeout_s`.
    pub const MQTT_UNACKNOWLEDGED: u16 = 1 << 2;
    /// The last attempt at a sample failed on the rig.
    pub const DEVICE_ERROR: u16 = 1 << 3;
    /// The broker refused the login.
    pub const MQTT_REFUSED: u16 = 1 << 4;
}

/// Codes of register 16.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ErrorCode {
    /// None.
    #[default]
    None = 0,
    /// A sweep failed on the rig.
    Device = 1,
    /// The disk is full or below its floor.
    DiskFull = 2,
    /// The broker does not acknowledge.
    MqttUnacknowledged = 3,
    /// The broker refused the login.
    MqttRefused = 4,
}

/// The line as a PLC sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Snapshot {
    /// Register 1.
    pub state: LineState,
    /// Counter of the last sample judged.
    pub counter: u32,
    /// `Some(true)` PASS, `Some(false)` FAIL.
    pub pass: Option<bool>,
    /// [`alarm_bit`]s.
    pub alarm_bits: u16,
    /// Mean, smallest and largest thickness, nm.
    pub thickness_nm: [f32; 3],
    /// Index at 550 nm.
    pub index_550: f32,
    /// Valid share of the judged pixels.
    pub valid_fraction: f32,
    /// Register 16.
    pub last_error: ErrorCode,
}

impl Default for Snapshot {
    fn default() -> Self {
        Self {
            state: LineState::Starting,
            counter: 0,
            pass: None,
            alarm_bits: 0,
            thickness_nm: [f32::NAN; 3],
            index_550: f32::NAN,
            valid_fraction: f32::NAN,
            last_error: ErrorCode::None,
        }
    }
}

/// `v` as two words, high word first.
pub fn f32_words(v: f32) -> [u16; 2] {
    let b = v.to_bits();
    [(b >> 16) as u16, b as u16]
}

impl Snapshot {
    /// The register map of the [module docs](self).
    pub fn registers(&self, heartbeat: u16, triggers: u16) -> [u16; REGISTERS as usize] {
        let mut r = [0u16; REGISTERS as usize];
        let [t0, t1, t2] = self.thickness_nm;
        let floats = [t0, t1, t2, self.index_550, self.valid_fraction];
        r[0] = heartbeat;
        r[1] = self.state as u16;
        r[2] = (self.counter >> 16) as u16;
        r[3] = self.counter as u16;
        r[4] = match self.pass {
            None => 0,
            Some(true) => 1,
            Some(false) => 2,
        };
        r[5] = self.alarm_bits;
        for (i, v) in floats.into_iter().enumerate() {
            let [hi, lo] = f32_words(v);
            r[6 + 2 * i] = hi;
            r[7 + 2 * i] = lo;
        }
        r[16] = self.last_error as u16;
        r[17] = triggers;
        r
    }
}

/// A Modbus server that cannot start: one line naming the address.
#[derive(Debug, thiserror::Error)]
#[error("modbus server on {addr}: {problem}")]
pub struct PlcError {
    /// Where it was to listen.
    pub addr: String,
    /// Why it cannot.
    pub problem: super::listen::ListenError,
}

/// What the server and the line share.
#[derive(Default)]
struct Shared {
    snapshot: Mutex<Snapshot>,
    trigger: AtomicBool,
    triggers: AtomicU16,
    heartbeat: AtomicU16,
    connections: AtomicUsize,
}

impl Shared {
    fn registers(&self) -> [u16; REGISTERS as usize] {
        let s = *self.snapshot.lock().unwrap_or_else(|p| p.into_inner());
        s.registers(
            self.heartbeat.load(Ordering::SeqCst),
            self.triggers.load(Ordering::SeqCst),
        )
    }

    /// The answer to one request: reads of the map and the coil, writes of the coil.
    fn answer(&self, req: Request<'_>) -> Result<Response, ExceptionCode> {
        let span = |addr: u16, n: u16, len: u16| {
            let end = u32::from(addr) + u32::from(n);
            if n == 0 || end > u32::from(len) {
                Err(ExceptionCode::IllegalDataAddress)
            } else {
                Ok(usize::from(addr)..end as usize)
            }
        };
        match req {
            Request::ReadHoldingRegisters(a, n) | Request::ReadInputRegisters(a, n) => {
                let words = self
                    .registers()
                    .get(span(a, n, REGISTERS)?)
                    .map(<[u16]>::to_vec);
                let words = words.ok_or(ExceptionCode::IllegalDataAddress)?;
                Ok(match req {
                    Request::ReadHoldingRegisters(..) => Response::ReadHoldingRegisters(words),
                    _ => Response::ReadInputRegisters(words),
                })
            }
            Request::ReadCoils(a, n) => {
                span(a, n, COILS)?;
                Ok(Response::ReadCoils(vec![self
                    .trigger
                    .load(Ordering::SeqCst)]))
            }
            Request::WriteSingleCoil(a, v) => {
                span(a, 1, COILS)?;
                self.trigger.store(v, Ordering::SeqCst);
                Ok(Response::WriteSingleCoil(a, v))
            }
            Request::WriteMultipleCoils(a, ref v) => {
                span(a, v.len() as u16, COILS)?;
                if let Some(&b) = v.first() {
                    self.trigger.store(b, Ordering::SeqCst);
                }
                Ok(Response::WriteMultipleCoils(a, v.len() as u16))
            }
            Request::WriteSingleRegister(..) | Request::WriteMultipleRegisters(..) => {
                Err(ExceptionCode::IllegalDataAddress)
            }
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }
}

/// One client's service; its drop frees its connection slot.
struct Service {
    shared: Arc<Shared>,
}

impl Drop for Service {
    fn drop(&mut self) {
        self.shared.connections.fetch_sub(1, Ordering::SeqCst);
    }
}

impl tokio_modbus::server::Service for Service {
    type Request = Request<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Response, ExceptionCode>>;

    fn call(&self, req: Self::Request) -> Self::Future {
        std::future::ready(self.shared.answer(req))
    }
}

/// The Modbus TCP server of the [module docs](self).
pub struct PlcServer {
    shared: Arc<Shared>,
    server: ServerThread,
}

impl PlcServer {
    /// Listens on `bind` (`host:port`, port 0: any free one). Fails, naming the address,
    /// when it cannot listen there.
    pub fn start(bind: &str) -> Result<Self, PlcError> {
        let shared = Arc::new(Shared::default());
        let sh = shared.clone();
        let server = ServerThread::start(bind, "modbus", move |listener, stopped| {
            serve(listener, sh, stopped)
        })
        .map_err(|problem| PlcError {
            addr: bind.to_owned(),
            problem,
        })?;
        Ok(Self { shared, server })
    }

    /// Where it listens.
    pub fn addr(&self) -> SocketAddr {
        self.server.addr()
    }

    /// Changes the snapshot the registers show.
    pub fn update(&self, f: impl FnOnce(&mut Snapshot)) {
        f(&mut self
            .shared
            .snapshot
            .lock()
            .unwrap_or_else(|p| p.into_inner()));
    }

    /// Whether the trigger coil is set; clears it (and counts a trigger) if so.
    pub fn take_trigger(&self) -> bool {
        let set = self.shared.trigger.swap(false, Ordering::SeqCst);
        if set {
            self.shared.triggers.fetch_add(1, Ordering::SeqCst);
        }
        set
    }
}

async fn serve(
    listener: std::net::TcpListener,
    shared: Arc<Shared>,
    stopped: tokio::sync::oneshot::Receiver<()>,
) {
    let Ok(listener) = tokio::net::TcpListener::from_std(listener) else {
        return;
    };
    let hb = shared.clone();
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        tick.tick().await;
        loop {
            tick.tick().await;
            hb.heartbeat.fetch_add(1, Ordering::SeqCst);
        }
    });
    let server = tokio_modbus::server::tcp::Server::new(listener);
    let on_connected = |stream: tokio::net::TcpStream, _addr: SocketAddr| {
        let shared = shared.clone();
        async move {
            if shared.connections.fetch_add(1, Ordering::SeqCst) >= MAX_CONNECTIONS {
                shared.connections.fetch_sub(1, Ordering::SeqCst);
                return Ok(None);
            }
            Ok(Some((Service { shared }, stream)))
        }
    };
    let stop = async move {
        let _ = stopped.await;
    };
    let _ = server.serve_until(&on_connected, |_err| {}, stop).await;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_register_map_encodes_as_documented() {
        let s = Snapshot {
            state: LineState::WaitingForTrigger,
            counter: 0x0001_0002,
            pass: Some(false),
            alarm_bits: alarm_bit::RUN_RULE | alarm_bit::DEVICE_ERROR,
            thickness_nm: [620.5, 600.0, 640.25],
            index_550: 2.1,
            valid_fraction: 1.0,
            last_error: ErrorCode::Device,
        };
        let r = s.registers(7, 3);
        assert_eq!(r[..6], [7, 1, 1, 2, 2, 0b1001]);
        let f = |i: usize| f32::from_bits((u32::from(r[i]) << 16) | u32::from(r[i + 1]));
        assert_eq!(
            [f(6), f(8), f(10), f(12), f(14)],
            [620.5, 600.0, 640.25, 2.1, 1.0]
        );
        assert_eq!((r[16], r[17]), (1, 3));
        // 620.5 = 0x441B2000: high word first.
        assert_eq!(r[6..8], [0x441B, 0x2000]);
        let none = Snapshot::default().registers(0, 0);
        assert_eq!(none[4], 0);
        assert!(f32::from_bits((u32::from(none[6]) << 16) | u32::from(none[7])).is_nan());
    }

    #[test]
    fn reads_past_the_map_and_writes_of_registers_are_refused() {
        let sh = Shared::default();
        assert!(matches!(
            sh.answer(Request::ReadHoldingRegisters(0, REGISTERS)),
            Ok(Response::ReadHoldingRegisters(w)) if w.len() == REGISTERS as usize
        ));
        for req in [
            Request::ReadInputRegisters(17, 2),
            Request::ReadHoldingRegisters(0, 0),
            Request::ReadHoldingRegisters(u16::MAX, 2),
            Request::WriteSingleRegister(1, 5),
            Request::WriteSingleCoil(1, true),
            Request::ReadCoils(0, 2),
        ] {
            assert_eq!(
                sh.answer(req.clone()).err(),
                Some(ExceptionCode::IllegalDataAddress),
                "{req:?}"
            );
        }
        assert!(sh.answer(Request::WriteSingleCoil(0, true)).is_ok());
        assert!(sh.trigger.load(Ordering::SeqCst));
    }
}
