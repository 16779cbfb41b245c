//! The trainee page's HTTP server: the page and its bundled script (compiled into the
//! binary, nothing fetched at run time), a server-sent-event stream of the session, the
//! current state as JSON, and the answer endpoint of grade training. A small std-only
//! HTTP/1.1 server: one thread per connection, each browser with its own bounded queue
//! (a slow browser loses events, counted; it never holds up the others).

use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::mapping::PageEvent;
use crate::source::Counters;

pub const INDEX_HTML: &str = include_str!("../web/index.html");
pub const VIEWER_JS: &str = include_str!("../web/dist/viewer.js");
pub const LICENSES: &str = include_str!("../web/dist/LICENSES.txt");

/// Events queued per browser before it starts losing them.
const CLIENT_QUEUE: usize = 256;

/// Fan-out of page events to connected browsers, with the newest of each kind kept for a
/// browser that connects later.
#[derive(Default)]
pub struct Hub {
    clients: Mutex<Vec<SyncSender<PageEvent>>>,
    latest: Mutex<HashMap<&'static str, PageEvent>>,
}

impl Hub {
    pub fn broadcast(&self, event: PageEvent, counters: &Counters) {
        if let Ok(mut latest) = self.latest.lock() {
            latest.insert(event.name, event.clone());
        }
        if let Ok(mut clients) = self.clients.lock() {
            clients.retain(|c| match c.try_send(event.clone()) {
                Ok(()) => true,
                Err(TrySendError::Full(_)) => {
                    counters.dropped_page.fetch_add(1, Ordering::Relaxed);
                    true
                }
                Err(TrySendError::Disconnected(_)) => false,
            });
        }
    }

    fn subscribe(&self) -> Receiver<PageEvent> {
        let (tx, rx) = sync_channel(CLIENT_QUEUE);
        // The newest topology first (the mesh needs it), then the rest.
        if let Ok(latest) = self.latest.lock() {
            for name in ["topology", "mesh", "state", "training"] {
                if let Some(e) = latest.get(name) {
                    let _ = tx.try_send(e.clone());
                }
            }
        }
        if let Ok(mut clients) = self.clients.lock() {
            clients.push(tx);
        }
        rx
    }

    pub fn latest_json(&self, name: &str) -> Option<Arc<str>> {
        self.latest
            .lock()
            .ok()
            .and_then(|l| l.get(name).map(|e| e.data.clone()))
    }

    pub fn client_count(&self) -> usize {
        self.clients.lock().map(|c| c.len()).unwrap_or(0)
    }
}

/// What a request handler needs.
pub struct Shared {
    pub hub: Arc<Hub>,
    pub counters: Arc<Counters>,
    /// Answers from the page to the shared-memory thread: (case, grade).
    pub answers: SyncSender<(u32, u32)>,
    pub stop: &'static AtomicBool,
}

/// Binds the page's listener (fails at once when the port is taken).
pub fn bind(addr: SocketAddr) -> std::io::Result<TcpListener> {
    TcpListener::bind(addr)
}

/// Accepts connections until `stop`.
pub fn serve(listener: TcpListener, shared: Arc<Shared>) {
    let _ = listener.set_nonblocking(true);
    while !shared.stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((stream, _)) => {
                let shared = shared.clone();
                std::thread::spawn(move || {
                    let _ = stream.set_nonblocking(false);
                    if let Err(e) = handle(stream, &shared) {
                        tracing::debug!("http connection: {e}");
                    }
                });
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => {
                tracing::warn!("http accept: {e}");
                std::thread::sleep(Duration::from_millis(100));
            }
        }
    }
}

struct Request {
    method: String,
    path: String,
    body: Vec<u8>,
}

fn read_request(stream: &TcpStream) -> std::io::Result<Option<Request>> {
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut reader = BufReader::new(stream);
    let mut line = String::new();
    if reader.read_line(&mut line)? == 0 {
        return Ok(None);
    }
    let mut parts = line.split_whitespace();
    let (Some(method), Some(target)) = (parts.next(), parts.next()) else {
        return Ok(None);
    };
    let (method, path) = (method.to_string(), target.to_string());
    let mut length = 0usize;
    loop {
        let mut header = String::new();
        if reader.read_line(&mut header)? == 0 || header == "\r\n" || header == "\n" {
            break;
        }
        if let Some((k, v)) = header.split_once(':') {
            if k.trim().eq_ignore_ascii_case("content-length") {
                length = v.trim().parse().unwrap_or(0).min(4096);
            }
        }
    }
    let mut body = vec![0; length];
    reader.read_exact(&mut body)?;
    Ok(Some(Request { method, path, body }))
}

fn respond(mut stream: &TcpStream, code: &str, kind: &str, body: &[u8]) -> std::io::Result<()> {
    write!(
        stream,
        "HTTP/1.1 {code}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n",
        body.len()
    )?;
    stream.write_all(body)?;
    stream.flush()
}

/// `case=K&grade=G` (form or query string) → (case, grade).
pub fn parse_answer(text: &str) -> Option<(u32, u32)> {
    let mut case = None;
    let mut grade = None;
    for pair in text.trim().split('&') {
        match pair.split_once('=') {
            Some(("case", v)) => case = v.parse().ok(),
            Some(("grade", v)) => grade = v.parse().ok(),
            _ => {}
        }
    }
    Some((case?, grade?))
}

fn handle(stream: TcpStream, shared: &Shared) -> std::io::Result<()> {
    let Some(req) = read_request(&stream)? else {
        return Ok(());
    };
    let (path, query) = req.path.split_once('?').unwrap_or((&req.path, ""));
    match (req.method.as_str(), path) {
        ("GET", "/") | ("GET", "/index.html") => respond(
            &stream,
            "200 OK",
            "text/html; charset=utf-8",
            INDEX_HTML.as_bytes(),
        ),
        ("GET", "/viewer.js") => respond(
            &stream,
            "200 OK",
            "text/javascript; charset=utf-8",
            VIEWER_JS.as_bytes(),
        ),
        ("GET", "/licenses.txt") => respond(
            &stream,
            "200 OK",
            "text/plain; charset=utf-8",
            LICENSES.as_bytes(),
        ),
        ("GET", "/state.json") => {
            let state = shared.hub.latest_json("state");
            let training = shared.hub.latest_json("training");
            let c = &shared.counters;
            let body = format!(
                "{{\"state\":{},\"training\":{},\"browsers\":{},\"contact_frames\":{},\"surfaces\":{},\"dropped\":{},\"dropped_page\":{}}}",
                state.as_deref().unwrap_or("null"),
                training.as_deref().unwrap_or("null"),
                shared.hub.client_count(),
                c.contact_frames.load(Ordering::Relaxed),
                c.surfaces.load(Ordering::Relaxed),
                c.dropped.load(Ordering::Relaxed),
                c.dropped_page.load(Ordering::Relaxed),
            );
            respond(&stream, "200 OK", "application/json", body.as_bytes())
        }
        ("GET", "/events") => events(stream, shared),
        ("POST", "/answer") => {
            let body = String::from_utf8_lossy(&req.body);
            let parsed = parse_answer(&body).or_else(|| parse_answer(query));
            match parsed {
                Some(answer) if answer.1 < 16 => match shared.answers.try_send(answer) {
                    Ok(()) => respond(&stream, "202 Accepted", "text/plain", b"answer sent\n"),
                    Err(_) => respond(
                        &stream,
                        "503 Service Unavailable",
                        "text/plain",
                        b"answer queue full, try again\n",
                    ),
                },
                _ => respond(
                    &stream,
                    "400 Bad Request",
                    "text/plain",
                    b"expected case=K&grade=G\n",
                ),
            }
        }
        ("GET", _) => respond(&stream, "404 Not Found", "text/plain", b"not found\n"),
        _ => respond(
            &stream,
            "405 Method Not Allowed",
            "text/plain",
            b"method not allowed\n",
        ),
    }
}

fn events(mut stream: TcpStream, shared: &Shared) -> std::io::Result<()> {
    stream.set_write_timeout(Some(Duration::from_secs(5)))?;
    write!(
        stream,
        "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\nConnection: keep-alive\r\n\r\nretry: 500\n\n"
    )?;
    stream.flush()?;
    let rx = shared.hub.subscribe();
    let mut buf = Vec::with_capacity(64 * 1024);
    while !shared.stop.load(Ordering::Relaxed) {
        match rx.recv_timeout(Duration::from_secs(2)) {
            Ok(event) => {
                buf.clear();
                buf.extend_from_slice(b"event: ");
                buf.extend_from_slice(event.name.as_bytes());
                buf.extend_from_slice(b"\ndata: ");
                buf.extend_from_slice(event.data.as_bytes());
                buf.extend_from_slice(b"\n\n");
                stream.write_all(&buf)?;
            }
            Err(RecvTimeoutError::Timeout) => stream.write_all(b": keep-alive\n\n")?,
            Err(RecvTimeoutError::Disconnected) => break,
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_parse_from_forms() {
        assert_eq!(parse_answer("case=3&grade=2"), Some((3, 2)));
        assert_eq!(parse_answer("grade=0&case=1\n"), Some((1, 0)));
        assert_eq!(parse_answer("grade=x&case=1"), None);
        assert_eq!(parse_answer(""), None);
    }
}
