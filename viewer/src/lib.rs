//! viewer: a live picture of a session without ROS. One node process with three parts:
//!
//! - the shared-memory thread ([`source`]) reads the newest physics, haptic and surface
//!   samples (like the bridge, never slowing the 1 kHz loop) and converts them at the
//!   viewer's rates through [`mapping`] (the bridge's ROS 2 mapping);
//! - the output thread CDR-encodes the ROS 2 messages onto Foxglove WebSocket channels
//!   (`foxglove` SDK; the Foxglove app connects to `ws://HOST:ws_port`) and fans the page
//!   events out to browsers;
//! - the HTTP server ([`http`]) serves the trainee page (three.js, bundled at build time and
//!   compiled into the binary) and its event stream.
//!
//! Queues between them are bounded and drop (and count) when full.

pub mod http;
pub mod mapping;
pub mod source;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, RecvTimeoutError};
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context as _;
use launch_config::{BridgeConfig, ViewerConfig};
use msgs::ros_mapping::StampClock;

use crate::mapping::{Channel, CHANNELS};
use crate::source::{Counters, Rates, Update};

/// Command-line arguments of the viewer node (`arthrosim node viewer`).
#[derive(Debug, Clone, clap::Args)]
pub struct NodeArgs {
    /// Launch file (TOML); its `[viewer]` section configures this node, its `[bridge]`
    /// section the topic namespace and frames. No file: defaults.
    #[arg(long, value_name = "FILE")]
    pub launch: Option<PathBuf>,
    /// Session name (shared-memory prefix); default `$ARTHROSIM_SESSION` or `default`.
    #[arg(long, value_name = "NAME")]
    pub session: Option<String>,
    /// Output directory (the viewer writes no files; accepted for a uniform node CLI).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

/// The `[viewer]` and `[bridge]` sections of a launch file (no file: defaults).
pub fn load_config(path: Option<&Path>) -> anyhow::Result<(ViewerConfig, BridgeConfig)> {
    let (viewer, bridge) = match path {
        None => (ViewerConfig::default(), BridgeConfig::default()),
        Some(path) => {
            let file = launch_config::load(path)
                .with_context(|| format!("loading launch file {}", path.display()))?;
            (file.viewer, file.bridge)
        }
    };
    viewer.validate()?;
    Ok((viewer, bridge))
}

/// Foxglove channels of one server, indexed by [`Channel`].
struct FoxgloveOut {
    /// Owns the channels' registry: dropping it would close them.
    _context: Arc<foxglove::Context>,
    _server: foxglove::WebSocketServerHandle,
    channels: Vec<Arc<foxglove::RawChannel>>,
}

fn start_foxglove(
    addr: SocketAddr,
    namespace: &str,
) -> Result<(FoxgloveOut, u16), foxglove::FoxgloveError> {
    // Our own context, so nothing else in the process logs onto these channels.
    let context = foxglove::Context::new();
    let mut channels = Vec::with_capacity(CHANNELS);
    for ch in Channel::ALL {
        let (name, text) = ch.schema();
        let channel = foxglove::ChannelBuilder::new(ch.topic(namespace))
            .context(&context)
            .message_encoding("cdr")
            .schema(foxglove::Schema::new(name, "ros2msg", text.into_bytes()))
            .build_raw()?;
        channels.push(channel);
    }
    let server = foxglove::WebSocketServer::new()
        .name("arthrosim")
        .context(&context)
        .bind(addr.ip().to_string(), addr.port())
        .start_blocking()?;
    let port = server.port();
    Ok((
        FoxgloveOut {
            _context: context,
            _server: server,
            channels,
        },
        port,
    ))
}

/// Default log filter (override with RUST_LOG).
const QUIET_LOGS: &str = "warn";

/// Runs the viewer node until SIGINT / SIGTERM.
pub fn run_node(args: NodeArgs) -> anyhow::Result<()> {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(QUIET_LOGS)),
        )
        .with_writer(std::io::stderr)
        .try_init();
    let stop = msgs::lifecycle::install_stop_flag();
    let (config, bridge) = load_config(args.launch.as_deref())?;
    let session = msgs::ipc::session_name(args.session.as_deref())?;
    run(&config, &bridge, &session, stop)
}

/// The viewer: starts both servers and the shared-memory thread, prints
/// `VIEWER http=<url> ws=<url>` and `READY viewer`, and forwards until `stop`.
pub fn run(
    config: &ViewerConfig,
    bridge: &BridgeConfig,
    session: &str,
    stop: &'static AtomicBool,
) -> anyhow::Result<()> {
    config.validate()?;
    let ip = config.bind_addr()?;
    let counters = Arc::new(Counters::default());
    let hub = Arc::new(http::Hub::default());

    // A port that is taken (another session's viewer on this machine) costs this session
    // its viewer output, not the session itself: say so clearly and go on.
    let http_addr = SocketAddr::new(ip, config.http_port);
    let listener = match http::bind(http_addr) {
        Ok(l) => Some(l),
        Err(e) => {
            eprintln!(
                "viewer: cannot serve the trainee page on http://{http_addr}/ ({e}); set [viewer] http_port"
            );
            None
        }
    };
    let ws_addr = SocketAddr::new(ip, config.ws_port);
    let foxglove = match start_foxglove(ws_addr, &bridge.namespace) {
        Ok(f) => Some(f),
        Err(e) => {
            eprintln!(
                "viewer: cannot serve Foxglove WebSocket on ws://{ws_addr} ({e}); set [viewer] ws_port"
            );
            None
        }
    };
    let http_url = listener
        .as_ref()
        .and_then(|l| l.local_addr().ok())
        .map(|a| format!("http://{a}/"))
        .unwrap_or_else(|| "none".into());
    let ws_url = foxglove
        .as_ref()
        .map(|(_, port)| format!("ws://{}", SocketAddr::new(ip, *port)))
        .unwrap_or_else(|| "none".into());
    if config.is_lan() {
        eprintln!(
            "viewer: bound to {ip}: the live session and the training page are visible to every machine that can reach it"
        );
    }

    let (answers_tx, answers_rx) = sync_channel(16);
    if let Some(listener) = listener {
        let shared = Arc::new(http::Shared {
            hub: hub.clone(),
            counters: counters.clone(),
            answers: answers_tx,
            stop,
        });
        std::thread::Builder::new()
            .name("viewer-http".into())
            .spawn(move || http::serve(listener, shared))
            .context("starting the HTTP thread")?;
    }

    let (tx, rx) = sync_channel::<Update>(config.queue_depth);
    // The session's one stamp clock (ARTHROSIM_CLOCK_OFFSET_NS from the launcher), so the
    // viewer stamps a sample as the bridge and the recorder do.
    let clock = StampClock::for_session().context("the session stamp clock")?;
    let rates = Rates {
        state_period: Duration::from_secs_f64(1.0 / config.rate_hz),
        mesh_period: Duration::from_secs_f64(1.0 / config.mesh_rate_hz),
    };
    let frames = bridge.ros_mapping();
    let session_owned = session.to_string();
    let source_counters = counters.clone();
    let (ready_tx, ready_rx) = sync_channel::<()>(1);
    let source = std::thread::Builder::new()
        .name("viewer-ipc".into())
        .spawn(move || {
            source::run(
                &session_owned,
                frames,
                rates,
                clock,
                tx,
                answers_rx,
                source_counters,
                stop,
                move || {
                    let _ = ready_tx.send(());
                },
            )
        })
        .context("starting the shared-memory thread")?;
    if ready_rx.recv_timeout(Duration::from_secs(30)).is_err() {
        stop.store(true, Ordering::Relaxed);
        return match source.join() {
            Ok(Err(e)) => Err(e).context("opening the session's shared-memory streams"),
            _ => anyhow::bail!("the shared-memory thread did not start"),
        };
    }
    println!("VIEWER http={http_url} ws={ws_url}");
    msgs::lifecycle::announce_ready("viewer");

    // The output thread (this one): encode and publish.
    let mut buf = Vec::with_capacity(1 << 16);
    let fox = foxglove.map(|(f, _)| f);
    while !stop.load(Ordering::Relaxed) {
        match rx.recv_timeout(Duration::from_millis(200)) {
            Ok(Update::Ros { stamp_ns, msg }) => {
                let Some(fox) = &fox else { continue };
                let channel = &fox.channels[msg.channel() as usize];
                if !channel.has_sinks() {
                    continue; // nobody subscribed: skip the encoding
                }
                if let Err(e) = msg.encode(&mut buf) {
                    tracing::warn!("encoding {:?}: {e}", msg.channel());
                    continue;
                }
                channel.log_with_meta(
                    &buf,
                    foxglove::PartialMetadata::with_log_time(clock.epoch_ns(stamp_ns)),
                );
            }
            Ok(Update::Page(event)) => hub.broadcast(event, &counters),
            Err(RecvTimeoutError::Timeout) => {}
            Err(RecvTimeoutError::Disconnected) => break,
        }
    }
    stop.store(true, Ordering::Relaxed);
    let joined = source.join();
    println!("VIEWED {}", counters.totals_json());
    match joined {
        Ok(r) => r.context("shared-memory thread")?,
        Err(_) => anyhow::bail!("the shared-memory thread panicked"),
    }
    Ok(())
}
