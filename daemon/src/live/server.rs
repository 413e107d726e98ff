//! The live view's listener: one port for the operator page (`GET /`, plain HTTP) and the
//! Foxglove WebSocket protocol (an upgrade request offering `foxglove.websocket.v1`).
//!
//! The request head is read here (at most [`MAX_HEAD`] bytes, within [`HEAD_TIMEOUT`]), so the
//! daemon answers the WebSocket handshake itself (RFC 6455 §4.2.2, the accept key from
//! tungstenite) and hands the socket to tungstenite's framing.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::broadcast::error::{RecvError, TryRecvError};
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::handshake::derive_accept_key;
use tokio_tungstenite::tungstenite::protocol::{Role, WebSocketConfig};
use tokio_util::sync::CancellationToken;

use super::hub::{Hub, LiveMsg};
use super::protocol::{self, ClientOp};

/// Longest request head accepted.
pub const MAX_HEAD: usize = 16 << 10;
/// Time a client has to send its request head.
pub const HEAD_TIMEOUT: Duration = Duration::from_secs(10);
/// Largest message a client may send (subscribe lists are small).
const MAX_CLIENT_MESSAGE: usize = 1 << 20;
/// Longest a client may take to accept one message before it is disconnected.
pub const SEND_TIMEOUT: Duration = Duration::from_secs(10);
/// Least time between two journal warnings about one slow client.
const DROP_WARN_INTERVAL: Duration = Duration::from_secs(10);

/// The operator page (self-contained: no external resource).
pub const PAGE: &str = include_str!("page.html");

/// Accepts connections until `stop`.
pub async fn serve(listener: TcpListener, hub: Arc<Hub>, stop: CancellationToken) {
    let mut tasks = tokio::task::JoinSet::new();
    loop {
        tokio::select! {
            _ = stop.cancelled() => break,
            r = listener.accept() => match r {
                Ok((sock, peer)) => {
                    tasks.spawn(connection(sock, peer, hub.clone(), stop.clone()));
                }
                Err(e) => {
                    // Out of descriptors and the like: wait a little rather than spin.
                    tracing::warn!("live view: cannot accept a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(200)).await;
                }
            },
            Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
        }
    }
    while tasks.join_next().await.is_some() {}
}

/// A request head: method, path and headers (names in lower case).
#[derive(Debug, Default)]
pub struct Head {
    pub method: String,
    pub path: String,
    pub headers: HashMap<String, String>,
}

impl Head {
    pub fn parse(text: &str) -> Option<Head> {
        let mut lines = text.split("\r\n");
        let mut first = lines.next()?.split(' ');
        let (method, path) = (first.next()?.to_string(), first.next()?.to_string());
        let headers = lines
            .filter_map(|l| l.split_once(':'))
            .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
            .collect();
        Some(Head {
            method,
            path,
            headers,
        })
    }

    fn header(&self, name: &str) -> &str {
        self.headers.get(name).map(String::as_str).unwrap_or("")
    }

    fn has_token(&self, name: &str, token: &str) -> bool {
        self.header(name)
            .split(',')
            .any(|t| t.trim().eq_ignore_ascii_case(token))
    }

    pub fn is_websocket(&self) -> bool {
        self.has_token("upgrade", "websocket")
    }
}

async fn read_head(sock: &mut TcpStream) -> Option<String> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    while !buf.windows(4).any(|w| w == b"\r\n\r\n") {
        if buf.len() > MAX_HEAD {
            return None;
        }
        let n = sock.read(&mut chunk).await.ok()?;
        if n == 0 {
            return None;
        }
        buf.extend_from_slice(&chunk[..n]);
    }
    String::from_utf8(buf).ok()
}

async fn connection(mut sock: TcpStream, peer: SocketAddr, hub: Arc<Hub>, stop: CancellationToken) {
    let head = match tokio::time::timeout(HEAD_TIMEOUT, read_head(&mut sock)).await {
        Ok(Some(text)) => Head::parse(&text),
        _ => None,
    };
    let Some(head) = head else {
        let _ = reply(&mut sock, "400 Bad Request", "text/plain", "bad request\n").await;
        return;
    };
    if head.is_websocket() {
        websocket(sock, peer, &head, hub, stop).await;
    } else {
        http(&mut sock, &head).await;
    }
}

async fn reply(sock: &mut TcpStream, status: &str, ctype: &str, body: &str) -> std::io::Result<()> {
    let head = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n",
        body.len()
    );
    sock.write_all(head.as_bytes()).await?;
    sock.write_all(body.as_bytes()).await?;
    sock.shutdown().await
}

/// The operator page at `/`; nothing else is served.
async fn http(sock: &mut TcpStream, head: &Head) {
    let path = head.path.split('?').next().unwrap_or("");
    let r = match (head.method.as_str(), path) {
        ("GET", "/" | "/index.html") => reply(sock, "200 OK", "text/html; charset=utf-8", PAGE),
        ("GET", _) => reply(sock, "404 Not Found", "text/plain", "not found\n"),
        _ => reply(
            sock,
            "405 Method Not Allowed",
            "text/plain",
            "the live view is read-only\n",
        ),
    };
    let _ = r.await;
}

async fn websocket(
    mut sock: TcpStream,
    peer: SocketAddr,
    head: &Head,
    hub: Arc<Hub>,
    stop: CancellationToken,
) {
    let key = head.header("sec-websocket-key");
    if key.is_empty() || !head.has_token("sec-websocket-protocol", protocol::SUBPROTOCOL) {
        let msg = format!(
            "a WebSocket client must offer the subprotocol {}\n",
            protocol::SUBPROTOCOL
        );
        let _ = reply(&mut sock, "400 Bad Request", "text/plain", &msg).await;
        return;
    }
    let accept = format!(
        "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Accept: {}\r\nSec-WebSocket-Protocol: {}\r\n\r\n",
        derive_accept_key(key.as_bytes()),
        protocol::SUBPROTOCOL
    );
    if sock.write_all(accept.as_bytes()).await.is_err() {
        return;
    }
    let mut cfg = WebSocketConfig::default();
    cfg.max_message_size = Some(MAX_CLIENT_MESSAGE);
    cfg.max_frame_size = Some(MAX_CLIENT_MESSAGE);
    let ws = WebSocketStream::from_raw_socket(sock, Role::Server, Some(cfg)).await;
    tracing::info!("live view: client {peer} connected");
    let dropped = Session::new(hub, peer).run(ws, stop).await;
    tracing::info!("live view: client {peer} left; {dropped} messages skipped for it");
}

type Ws = WebSocketStream<TcpStream>;

/// Sends one message; false when the client is gone or has taken nothing for [`SEND_TIMEOUT`]
/// (a stalled client is let go rather than held on to).
async fn send(ws: &mut Ws, msg: Message, peer: SocketAddr) -> bool {
    match tokio::time::timeout(SEND_TIMEOUT, ws.send(msg)).await {
        Ok(r) => r.is_ok(),
        Err(_) => {
            tracing::warn!(
                "live view: client {peer} took nothing for {SEND_TIMEOUT:?}; disconnected"
            );
            false
        }
    }
}

/// One client: its subscriptions and what it missed.
struct Session {
    hub: Arc<Hub>,
    peer: SocketAddr,
    /// Subscription id by channel index, and the newest message sent on it (the stream may
    /// still hold a latched one sent on subscribing or after a lag: not sent twice).
    subs: HashMap<usize, (u32, Option<u64>)>,
    dropped: u64,
    last_warn: Option<Instant>,
}

impl Session {
    fn new(hub: Arc<Hub>, peer: SocketAddr) -> Session {
        Session {
            hub,
            peer,
            subs: HashMap::new(),
            dropped: 0,
            last_warn: None,
        }
    }

    /// Serves the client until it leaves, the run ends or `stop`; returns the messages it
    /// missed.
    async fn run(mut self, mut ws: Ws, stop: CancellationToken) -> u64 {
        let mut rx = self.hub.subscribe();
        let hello = [
            protocol::server_info(&self.hub.run),
            protocol::advertise(&self.hub.channels),
        ];
        for text in hello {
            if !send(&mut ws, Message::text(text), self.peer).await {
                return 0;
            }
        }
        loop {
            let ok = tokio::select! {
                _ = stop.cancelled() => {
                    // The run ended: what it wrote last (final pose values, /status) first.
                    while let Ok(m) = rx.try_recv() {
                        if !self.forward(&mut ws, &m).await {
                            break;
                        }
                    }
                    false
                }
                m = ws.next() => match m {
                    Some(Ok(Message::Text(t))) => self.on_text(&mut ws, t.as_str()).await,
                    Some(Ok(Message::Binary(_))) => {
                        let s = protocol::status(2, "the live view is read-only: clients cannot publish");
                        send(&mut ws, Message::text(s), self.peer).await
                    }
                    Some(Ok(Message::Close(_))) | Some(Err(_)) | None => false,
                    Some(Ok(_)) => true, // ping/pong: tungstenite answers pings itself
                },
                r = rx.recv() => match r {
                    Ok(m) => self.forward(&mut ws, &m).await,
                    Err(RecvError::Lagged(n)) => {
                        self.lagged(n);
                        self.resync(&mut ws).await
                    }
                    Err(RecvError::Closed) => false,
                },
            };
            if !ok {
                break;
            }
        }
        let before = self.dropped;
        self.count_unsent(&mut rx);
        self.hub
            .dropped
            .fetch_add(self.dropped - before, Ordering::Relaxed);
        let _ = tokio::time::timeout(SEND_TIMEOUT, ws.close(None)).await;
        self.dropped
    }

    async fn forward(&mut self, ws: &mut Ws, m: &LiveMsg) -> bool {
        let Some(&(sub, newest)) = self.subs.get(&m.channel) else {
            return true;
        };
        if newest.is_some_and(|seq| m.seq <= seq) {
            return true;
        }
        let frame = protocol::message_data(sub, m.log_ns, &m.data);
        self.subs.insert(m.channel, (sub, Some(m.seq)));
        send(ws, Message::binary(frame), self.peer).await
    }

    /// After messages were skipped for a slow client: the latched ones it has not had (each
    /// instrument's current pose, the last status and events), so a pose value or an alarm
    /// lost in the skip is not missing from its screen until the next one.
    async fn resync(&mut self, ws: &mut Ws) -> bool {
        let mut channels: Vec<usize> = self.subs.keys().copied().collect();
        channels.sort_unstable();
        for i in channels {
            for m in self.hub.latched(i) {
                if !self.forward(ws, &m).await {
                    return false;
                }
            }
        }
        true
    }

    /// What the client will not get any more: counted as skipped when it leaves.
    fn count_unsent(&mut self, rx: &mut tokio::sync::broadcast::Receiver<Arc<LiveMsg>>) {
        loop {
            match rx.try_recv() {
                Ok(m) if self.subs.contains_key(&m.channel) => self.dropped += 1,
                Ok(_) => {}
                Err(TryRecvError::Lagged(n)) => self.dropped += n,
                Err(_) => break,
            }
        }
    }

    fn lagged(&mut self, n: u64) {
        self.dropped += n;
        self.hub.dropped.fetch_add(n, Ordering::Relaxed);
        if self
            .last_warn
            .is_none_or(|t| t.elapsed() >= DROP_WARN_INTERVAL)
        {
            self.last_warn = Some(Instant::now());
            tracing::warn!(
                "live view: client {} is too slow; {} messages skipped for it so far (the log has them all)",
                self.peer,
                self.dropped
            );
        }
    }

    async fn on_text(&mut self, ws: &mut Ws, text: &str) -> bool {
        match protocol::parse_client(text) {
            ClientOp::Subscribe(list) => {
                for (sub, channel_id) in list {
                    let Some(i) = self.channel_index(channel_id) else {
                        let s = protocol::status(1, &format!("no channel {channel_id}"));
                        if !send(ws, Message::text(s), self.peer).await {
                            return false;
                        }
                        continue;
                    };
                    self.subs.insert(i, (sub, None));
                    for m in &self.hub.latched(i) {
                        if !self.forward(ws, m).await {
                            return false;
                        }
                    }
                }
                true
            }
            ClientOp::Unsubscribe(ids) => {
                self.subs.retain(|_, (s, _)| !ids.contains(s));
                true
            }
            ClientOp::Refused(op) => {
                let s = protocol::status(
                    1,
                    &format!("the live view is read-only: \"{op}\" is not supported"),
                );
                send(ws, Message::text(s), self.peer).await
            }
            ClientOp::Invalid(why) => {
                let s = protocol::status(2, &why);
                send(ws, Message::text(s), self.peer).await
            }
        }
    }

    fn channel_index(&self, channel_id: u64) -> Option<usize> {
        let i = usize::try_from(channel_id.checked_sub(1)?).ok()?;
        (i < self.hub.channels.len()).then_some(i)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_head_parses_and_upgrade_is_recognised() {
        let h = Head::parse(
            "GET /?x=1 HTTP/1.1\r\nHost: a\r\nUpgrade: WebSocket\r\nSec-WebSocket-Protocol: x, foxglove.websocket.v1\r\n\r\n",
        )
        .unwrap();
        assert_eq!(h.method, "GET");
        assert_eq!(h.path, "/?x=1");
        assert!(h.is_websocket());
        assert!(h.has_token("sec-websocket-protocol", protocol::SUBPROTOCOL));
        let plain = Head::parse("GET / HTTP/1.1\r\nHost: a\r\n\r\n").unwrap();
        assert!(!plain.is_websocket());
        assert!(Head::parse("").is_none());
    }

    #[test]
    fn the_page_is_self_contained() {
        for external in ["http://", "https://", "<link", " src=", "@import"] {
            assert!(!PAGE.contains(external), "{external} in the page");
        }
        assert!(PAGE.contains(protocol::SUBPROTOCOL));
    }
}
