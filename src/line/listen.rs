//! A TCP server on a tokio runtime and a thread of its own, isolated from the measuring
//! threads, stopped and joined when dropped: what the status page and the Modbus server
//! share.

use std::future::Future;
use std::net::{SocketAddr, TcpListener, ToSocketAddrs};
use std::thread::JoinHandle;

use tokio::sync::oneshot;

/// A running server; dropping it stops the serving future and joins its thread.
pub struct ServerThread {
    addr: SocketAddr,
    shutdown: Option<oneshot::Sender<()>>,
    thread: Option<JoinHandle<()>>,
}

/// Why a server could not start.
#[derive(Debug, thiserror::Error)]
pub enum ListenError {
    /// The address cannot be listened on.
    #[error("cannot listen: {0}")]
    Bind(std::io::Error),
    /// No runtime for it.
    #[error("no runtime: {0}")]
    Runtime(std::io::Error),
    /// No thread for it.
    #[error("no thread: {0}")]
    Thread(std::io::Error),
}

impl ServerThread {
    /// Listens on `bind` and runs `serve(listener, stopped)` on a current-thread runtime on
    /// a thread called `name` until `stopped` fires.
    pub fn start<F, Fut>(
        bind: impl ToSocketAddrs,
        name: &str,
        serve: F,
    ) -> Result<Self, ListenError>
    where
        F: FnOnce(TcpListener, oneshot::Receiver<()>) -> Fut + Send + 'static,
        Fut: Future<Output = ()>,
    {
        let listener = TcpListener::bind(bind).map_err(ListenError::Bind)?;
        listener.set_nonblocking(true).map_err(ListenError::Bind)?;
        let addr = listener.local_addr().map_err(ListenError::Bind)?;
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_io()
            .enable_time()
            .build()
            .map_err(ListenError::Runtime)?;
        let (shutdown, stopped) = oneshot::channel();
        let thread = std::thread::Builder::new()
            .name(name.into())
            .spawn(move || runtime.block_on(serve(listener, stopped)))
            .map_err(ListenError::Thread)?;
        Ok(Self {
            addr,
            shutdown: Some(shutdown),
            thread: Some(thread),
        })
    }

    /// The address it listens on (the port chosen when asked for port 0).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }
}

impl Drop for ServerThread {
    fn drop(&mut self) {
        if let Some(s) = self.shutdown.take() {
            let _ = s.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
