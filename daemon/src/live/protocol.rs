//! The read-only subset of the Foxglove WebSocket protocol (subprotocol
//! `foxglove.websocket.v1`, docs/live-view.md) that the live view speaks.
//!
//! Server to client: `serverInfo` (no capabilities: no client publishing, services or
//! parameters), `advertise` (every log channel, with the log's schema: JSON schemas as text,
//! protobuf `FileDescriptorSet`s in base64), binary `messageData` (opcode 1: u32 subscription
//! id, u64 log time in ns, the message bytes, little-endian), and `status` answers to requests
//! it does not serve. Client to server: `subscribe` and `unsubscribe`; everything else is
//! refused with a `status` warning.

use serde::Deserialize;
use serde_json::{Value, json};

use metrolog_log::ChannelSpec;

use super::hub::RunInfo;

/// The WebSocket subprotocol.
pub const SUBPROTOCOL: &str = "foxglove.websocket.v1";

/// Opcode of a binary `messageData` frame.
pub const MESSAGE_DATA: u8 = 1;

/// Channel id of the channel at `index` of the hub's channels (ids start at 1).
pub fn channel_id(index: usize) -> u64 {
    index as u64 + 1
}

/// `metadata` (string values, as the protocol wants): the machine, the temperature module's
/// channel names (in `/temperature`'s channel order, comma-separated; empty without a module)
/// and the trajectory as JSON text, `[[pose, x_mm, y_mm, z_mm], ...]` (`[]` without one), so
/// the page can say "pose k of N" and the target of the pose being measured, and the samples a
/// steady value averages (`window_samples`), against which the page counts a dwell's samples.
pub fn server_info(run: &RunInfo) -> String {
    let trajectory: Vec<Value> = run
        .trajectory
        .iter()
        .map(|r| json!([r.pose, r.x_mm, r.y_mm, r.z_mm]))
        .collect();
    json!({
        "op": "serverInfo",
        "name": concat!("metrolog ", env!("CARGO_PKG_VERSION")),
        "capabilities": [],
        "supportedEncodings": [],
        "metadata": {
            "machine": run.machine,
            "temperature_sensors": run.temperature_sensors.join(","),
            "trajectory": Value::Array(trajectory).to_string(),
            "window_samples": run.window_samples.to_string(),
        },
        "sessionId": run.session,
    })
    .to_string()
}

pub fn advertise(channels: &[ChannelSpec]) -> String {
    let list: Vec<Value> = channels
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let schema = if c.schema_encoding == "protobuf" {
                data_encoding::BASE64.encode(&c.schema)
            } else {
                String::from_utf8_lossy(&c.schema).into_owned()
            };
            json!({
                "id": channel_id(i),
                "topic": c.topic,
                "encoding": c.message_encoding,
                "schemaName": c.schema_name,
                "schema": schema,
                "schemaEncoding": c.schema_encoding,
            })
        })
        .collect();
    json!({ "op": "advertise", "channels": list }).to_string()
}

/// A `status` message (level 0 info, 1 warning, 2 error).
pub fn status(level: u8, message: &str) -> String {
    json!({ "op": "status", "level": level, "message": message }).to_string()
}

/// The binary `messageData` frame of one message.
pub fn message_data(subscription: u32, log_ns: u64, data: &[u8]) -> Vec<u8> {
    let mut v = Vec::with_capacity(13 + data.len());
    v.push(MESSAGE_DATA);
    v.extend_from_slice(&subscription.to_le_bytes());
    v.extend_from_slice(&log_ns.to_le_bytes());
    v.extend_from_slice(data);
    v
}

#[derive(Debug, Deserialize)]
#[serde(rename_all = "camelCase")]
pub struct Subscription {
    pub id: u32,
    pub channel_id: u64,
}

/// What a client asked.
#[derive(Debug, PartialEq)]
pub enum ClientOp {
    /// `(subscription id, channel id)` pairs.
    Subscribe(Vec<(u32, u64)>),
    Unsubscribe(Vec<u32>),
    /// An operation the live view does not serve (publishing, services, parameters ...).
    Refused(String),
    /// Not a message of the protocol.
    Invalid(String),
}

#[derive(Deserialize)]
#[serde(rename_all = "camelCase")]
struct Envelope {
    op: String,
    #[serde(default)]
    subscriptions: Vec<Subscription>,
    #[serde(default)]
    subscription_ids: Vec<u32>,
}

/// Parses a text message from a client.
pub fn parse_client(text: &str) -> ClientOp {
    let env: Envelope = match serde_json::from_str(text) {
        Ok(e) => e,
        Err(e) => return ClientOp::Invalid(format!("not a protocol message: {e}")),
    };
    match env.op.as_str() {
        "subscribe" => ClientOp::Subscribe(
            env.subscriptions
                .iter()
                .map(|s| (s.id, s.channel_id))
                .collect(),
        ),
        "unsubscribe" => ClientOp::Unsubscribe(env.subscription_ids),
        other => ClientOp::Refused(other.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn client_messages_parse_and_anything_else_is_refused() {
        let s =
            r#"{"op":"subscribe","subscriptions":[{"id":0,"channelId":5},{"id":1,"channelId":6}]}"#;
        assert_eq!(parse_client(s), ClientOp::Subscribe(vec![(0, 5), (1, 6)]));
        let u = r#"{"op":"unsubscribe","subscriptionIds":[1]}"#;
        assert_eq!(parse_client(u), ClientOp::Unsubscribe(vec![1]));
        let p = r#"{"op":"advertise","channels":[]}"#;
        assert_eq!(parse_client(p), ClientOp::Refused("advertise".into()));
        assert!(matches!(parse_client("{"), ClientOp::Invalid(_)));
        assert!(matches!(
            parse_client(r#"{"op":"subscribe","subscriptions":[{"id":-1,"channelId":1}]}"#),
            ClientOp::Invalid(_)
        ));
    }

    #[test]
    fn message_data_is_opcode_subscription_time_payload() {
        let f = message_data(7, 0x0102_0304_0506_0708, b"xy");
        assert_eq!(f[0], 1);
        assert_eq!(&f[1..5], &7u32.to_le_bytes());
        assert_eq!(&f[5..13], &0x0102_0304_0506_0708u64.to_le_bytes());
        assert_eq!(&f[13..], b"xy");
    }

    #[test]
    fn advertise_carries_every_log_channel_with_its_schema() {
        let chans = metrolog_log::channel_specs();
        let v: Value = serde_json::from_str(&advertise(&chans)).unwrap();
        let list = v["channels"].as_array().unwrap();
        assert_eq!(list.len(), chans.len());
        for (c, a) in chans.iter().zip(list) {
            assert_eq!(a["topic"], c.topic);
            let schema = a["schema"].as_str().unwrap();
            let bytes = if c.schema_encoding == "protobuf" {
                data_encoding::BASE64.decode(schema.as_bytes()).unwrap()
            } else {
                schema.as_bytes().to_vec()
            };
            assert_eq!(bytes, c.schema);
        }
    }
}
