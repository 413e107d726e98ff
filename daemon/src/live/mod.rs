//! The live view (docs/live-view.md): what the run writes to its log, streamed to Foxglove,
//! Lichtblick or the operator page while it runs, read-only.
//!
//! ```text
//! LogWriter ──tap (every message, after it is in the file)──▶ Hub: decimation of raw topics,
//!      │                                                        latest /pose, /status, /event
//!      ▼                                                        ──lossy broadcast──▶ clients
//!   the log (never waits on a viewer)
//! ```
//!
//! The tap runs on the pipeline thread and never blocks: it puts the message into a
//! `tokio::sync::broadcast` channel of [`BACKLOG`] messages, which overwrites the oldest
//! message a slow client has not taken yet; that client then skips what it missed (counted,
//! and reported in the journal). Messages keep the log's bytes, topics, schemas and encodings,
//! so a client decodes them exactly as it decodes the log.
//!
//! One TCP port serves both the Foxglove WebSocket protocol ([`protocol`], subprotocol
//! `foxglove.websocket.v1`) and the operator page ([`server`], `GET /`); [`hub`] is what the
//! tap and the sessions share.

pub mod hub;
pub mod protocol;
pub mod server;

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use anyhow::Context;
use metrolog_log::MessageTap;
use tokio_util::sync::CancellationToken;

pub use hub::{BACKLOG, Hub, LiveMsg, RunInfo, tap};

use crate::acquire::config::LiveConfig;

/// A running live view: the listener and its clients.
pub struct LiveView {
    hub: Arc<Hub>,
    addr: SocketAddr,
    raw_hz: u32,
    stop: CancellationToken,
    task: tokio::task::JoinHandle<()>,
}

impl LiveView {
    /// Binds `cfg.listen` and starts serving. A non-loopback address is warned about loudly:
    /// anyone who reaches it can watch the run. `run` is what clients are told about the run.
    pub async fn start(cfg: &LiveConfig, run: RunInfo) -> anyhow::Result<Self> {
        let listener = tokio::net::TcpListener::bind(cfg.listen)
            .await
            .with_context(|| {
                format!(
                    "cannot listen on {} for the live view; change [live] listen or free the port",
                    cfg.listen
                )
            })?;
        let addr = listener.local_addr().context("the live view's address")?;
        if !addr.ip().is_loopback() {
            tracing::warn!(
                "LIVE VIEW ON A NETWORK ADDRESS {addr}: anyone who can reach this host can watch the run (read-only, no password). Use listen = \"127.0.0.1:{}\" and an SSH tunnel unless this network is trusted (docs/live-view.md)",
                addr.port()
            );
        }
        let hub = Arc::new(Hub::new(run));
        let stop = CancellationToken::new();
        let task = tokio::spawn(server::serve(listener, hub.clone(), stop.clone()));
        tracing::info!(
            "live view: operator page http://{addr}/ ; Foxglove WebSocket ws://{addr} (read-only)"
        );
        Ok(LiveView {
            hub,
            addr,
            raw_hz: cfg.raw_hz,
            stop,
            task,
        })
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The tap to put on the run's log writer.
    pub fn tap(&self) -> MessageTap {
        tap(self.hub.clone(), self.raw_hz)
    }

    /// Closes every client and the listener; returns the messages slow clients skipped.
    pub async fn stop(self) -> u64 {
        self.stop.cancel();
        // Clients get what the run wrote last; one that takes nothing is cut off by
        // SEND_TIMEOUT, and this bound ends the rest (aborting the server drops every client).
        let mut task = self.task;
        let limit = server::SEND_TIMEOUT + std::time::Duration::from_secs(2);
        if tokio::time::timeout(limit, &mut task).await.is_err() {
            task.abort();
        }
        let dropped = self.hub.dropped.load(Ordering::Relaxed);
        tracing::info!(
            "live view closed; {dropped} messages skipped for slow clients (the log has them all)"
        );
        dropped
    }
}

#[cfg(test)]
mod tests {
    use tokio::sync::broadcast;

    use super::*;

    fn topic_index(hub: &Hub, topic: &str) -> usize {
        hub.channels.iter().position(|c| c.topic == topic).unwrap()
    }

    #[test]
    fn raw_topics_are_decimated_and_json_topics_latched() {
        let hub = Arc::new(Hub::new(RunInfo::default()));
        let mut rx = hub.subscribe();
        let mut t = tap(hub.clone(), 10);
        let raw = hub.channels[0].topic;
        for k in 0..100u64 {
            t(raw, k * 10_000_000, b"r"); // 100 batches of 10 ms: 1 s
        }
        for k in 0..10u64 {
            t("/pose", k, format!("{{\"pose\":{k}}}").as_bytes());
        }
        let mut raw_seen = 0;
        while let Ok(m) = rx.try_recv() {
            raw_seen += usize::from(m.channel == 0);
        }
        assert_eq!(raw_seen, 10);
        let latched = hub.latched(topic_index(&hub, "/pose"));
        assert_eq!(latched.len(), 8);
        assert_eq!(latched[7].data, b"{\"pose\":9}");
        assert_eq!(latched[0].log_ns, 2);
    }

    /// A live view and a raw WebSocket client of it with a 4 KB receive buffer (it stalls
    /// when it does not read), past the handshake.
    async fn view_and_small_client() -> (LiveView, tokio::net::TcpStream) {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let cfg = LiveConfig {
            listen: "127.0.0.1:0".parse().unwrap(),
            raw_hz: 10,
        };
        let view = LiveView::start(&cfg, RunInfo::default()).await.unwrap();
        let sock = tokio::net::TcpSocket::new_v4().unwrap();
        sock.set_recv_buffer_size(4096).unwrap();
        let mut c = sock.connect(view.addr()).await.unwrap();
        let hello = "GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n";
        c.write_all(hello.as_bytes()).await.unwrap();
        let mut head = [0u8; 12];
        c.read_exact(&mut head).await.unwrap();
        assert_eq!(&head, b"HTTP/1.1 101");
        (view, c)
    }

    /// A client that subscribes and then reads nothing: the tap goes on at once whatever it
    /// is sent, the client is counted as skipping messages, and stopping the view ends.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_stalled_client_neither_blocks_the_writer_nor_the_stop() {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let (view, mut c) = view_and_small_client().await;
        let status = view
            .hub
            .channels
            .iter()
            .position(|ch| ch.topic == "/status");
        let sub = format!(
            r#"{{"op":"subscribe","subscriptions":[{{"id":0,"channelId":{}}}]}}"#,
            status.unwrap() + 1
        );
        // A client frame: text, masked with a zero key (RFC 6455 5.3).
        let mut frame = vec![0x81, 0x80 | sub.len() as u8, 0, 0, 0, 0];
        frame.extend_from_slice(sub.as_bytes());
        c.write_all(&frame).await.unwrap();
        // The session has subscribed once the latched /status reaches the client.
        let mut tap = view.tap();
        tap("/status", 0, b"{\"latched\":1}");
        let mut got = Vec::new();
        while !got.windows(13).any(|w| w == b"{\"latched\":1}") {
            let mut buf = [0u8; 4096];
            let n = c.read(&mut buf).await.unwrap();
            assert!(n > 0, "closed early");
            got.extend_from_slice(&buf[..n]);
        }
        // Now the client stalls under 64 MB of /status.
        let big = vec![b' '; 64 << 10];
        for k in 0..1024u64 {
            tap("/status", k, &big);
        }
        let dropped = tokio::time::timeout(std::time::Duration::from_secs(60), view.stop())
            .await
            .expect("stop ends");
        assert!(dropped > 0, "skipped messages are counted");
        drop(c);
    }

    /// A client that stalls while a pose value is published, long enough that the value is
    /// skipped for it: when it reads again it still gets that value (the latched ones it has
    /// not had are sent after a skip), not only the messages after the skip.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_client_that_lagged_gets_the_latched_pose_it_missed() {
        use tokio::io::{AsyncReadExt, AsyncWriteExt};
        let (view, mut c) = view_and_small_client().await;
        let (status, pose) = (
            topic_index(&view.hub, "/status") + 1,
            topic_index(&view.hub, "/pose") + 1,
        );
        let sub = format!(
            r#"{{"op":"subscribe","subscriptions":[{{"id":0,"channelId":{status}}},{{"id":1,"channelId":{pose}}}]}}"#
        );
        // A client frame: text, masked with a zero key (RFC 6455 5.3), 16-bit length.
        let mut frame = vec![0x81, 0x80 | 126, (sub.len() >> 8) as u8, sub.len() as u8];
        frame.extend_from_slice(&[0, 0, 0, 0]);
        frame.extend_from_slice(sub.as_bytes());
        c.write_all(&frame).await.unwrap();
        let mut tap = view.tap();
        tap("/status", 0, b"{\"latched\":1}");
        let mut got = Vec::new();
        let mut read_until = async |c: &mut tokio::net::TcpStream, what: &[u8]| {
            while !got.windows(what.len()).any(|w| w == what) {
                let mut buf = [0u8; 65536];
                let n = c.read(&mut buf).await.unwrap();
                assert!(n > 0, "closed early");
                got.extend_from_slice(&buf[..n]);
            }
        };
        read_until(&mut c, b"{\"latched\":1}").await;
        // The client stalls; meanwhile a pose value, and more than the backlog after it.
        let big = vec![b' '; 64 << 10];
        for k in 0..64u64 {
            tap("/status", k, &big);
        }
        tap(
            "/pose",
            1,
            br#"{"instrument":"interferometer","pose":3,"status":"MISSED"}"#,
        );
        for k in 0..(2 * BACKLOG as u64) {
            tap("/status", k, b"{}");
        }
        tap("/status", 2, b"{\"last\":1}");
        // Reading again: the pose value comes (after the skip), and the stream goes on.
        let read = async {
            read_until(&mut c, b"\"MISSED\"").await;
        };
        tokio::time::timeout(std::time::Duration::from_secs(60), read)
            .await
            .expect("the pose value skipped for the slow client reaches it after the skip");
        let dropped = view.stop().await;
        assert!(dropped > 0, "the client did lag: {dropped}");
        drop(c);
    }

    #[test]
    fn a_slow_client_loses_the_oldest_and_the_sender_never_waits() {
        let hub = Arc::new(Hub::new(RunInfo::default()));
        let mut rx = hub.subscribe();
        let mut t = tap(hub.clone(), 10);
        for k in 0..(BACKLOG as u64 + 10) {
            t("/status", k, b"{}");
        }
        match rx.try_recv() {
            Err(broadcast::error::TryRecvError::Lagged(n)) => assert_eq!(n, 10),
            other => panic!("{other:?}"),
        }
        assert_eq!(rx.try_recv().unwrap().log_ns, 10);
    }
}
