//! The checks of a config's devices before a run (`metrolog run --check`, and at every start):
//! no device named by two keys, every port present (unless `hotplug = true`) and a device.
//!
//! A missing port is a mistake by default: a typo in a device path must not become a run that
//! waits forever. An instrument plugged in for each test (the kit lives in a case between
//! tests) is configured with `hotplug = true`: then its absence is a note, the service waits
//! for it, and the "nothing connected" alarm ([`crate::acquire::pipeline`]) tells when it
//! never comes.

use std::os::unix::fs::FileTypeExt as _;
use std::path::{Path, PathBuf};

/// A device a config names (a serial port, or a SocketCAN interface), and where.
#[derive(Debug, Clone, PartialEq)]
pub struct PortSpec {
    /// Section and key, e.g. `[interferometer] port`.
    pub key: String,
    /// The device path (or interface name) as written.
    pub path: String,
    /// A network interface (SocketCAN), not a device file.
    pub interface: bool,
    /// `hotplug = true`: the device may be absent at start; the service waits for it.
    pub hotplug: bool,
    pub line: usize,
    pub column: usize,
}

/// Where a SocketCAN interface shows when it exists.
const NET_CLASS: &str = "/sys/class/net";

/// What a port names now: the canonical device path (udev symlinks resolved) if it exists.
fn canonical(p: &PortSpec) -> Option<PathBuf> {
    if p.interface {
        return None;
    }
    std::fs::canonicalize(&p.path).ok()
}

/// Ports named by two keys (the same text, or two paths that lead to one device): the later
/// key with the message.
pub fn shared_ports(ports: &[PortSpec]) -> Vec<(&PortSpec, String)> {
    let resolved: Vec<Option<PathBuf>> = ports.iter().map(canonical).collect();
    let mut found = Vec::new();
    for (j, b) in ports.iter().enumerate() {
        let first = ports[..j].iter().enumerate().find(|(i, a)| {
            a.interface == b.interface
                && (a.path == b.path || (resolved[*i].is_some() && resolved[*i] == resolved[j]))
        });
        if let Some((i, a)) = first {
            let same = if a.path == b.path {
                String::new()
            } else {
                format!(
                    " ({} and {} are both {})",
                    a.path,
                    b.path,
                    resolved[i].as_deref().unwrap_or(Path::new("?")).display()
                )
            };
            found.push((
                b,
                format!(
                    "{} = {:?} is already {} (line {}){same}; two instruments cannot share a port: give each its own",
                    b.key, b.path, a.key, a.line
                ),
            ));
        }
    }
    found
}

/// Ports that are missing (and not `hotplug`) or exist but are no device: the key with the
/// message.
pub fn missing_ports(ports: &[PortSpec]) -> Vec<(&PortSpec, String)> {
    ports
        .iter()
        .filter_map(|p| port_problem(p).map(|m| (p, m)))
        .collect()
}

fn port_problem(p: &PortSpec) -> Option<String> {
    if p.interface {
        let present = Path::new(NET_CLASS).join(&p.path).exists();
        return (!present && !p.hotplug).then(|| {
            format!(
                "{} = {:?}: no such network interface (see `ip link`); bring it up first, or set hotplug = true if it appears later",
                p.key, p.path
            )
        });
    }
    match std::fs::metadata(&p.path) {
        Ok(m) if m.file_type().is_char_device() => None,
        Ok(_) => Some(format!(
            "{} = {:?} exists but is not a device (a serial port is a character device such as /dev/ttyUSB0)",
            p.key, p.path
        )),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => (!p.hotplug).then(|| {
            format!(
                "{} = {:?} does not exist; plug the instrument in and check the udev rule (ls -l /dev/metrolog-*), or set hotplug = true if it is plugged in later",
                p.key, p.path
            )
        }),
        Err(e) => Some(format!("{} = {:?} cannot be examined: {e}", p.key, p.path)),
    }
}

/// Notes on ports that are not mistakes: a `hotplug` device absent now, a port this user
/// cannot open for reading and writing (the service's user, in `dialout`, may).
pub fn port_notes(ports: &[PortSpec]) -> Vec<String> {
    ports.iter().filter_map(port_note).collect()
}

fn port_note(p: &PortSpec) -> Option<String> {
    if p.interface {
        let present = Path::new(NET_CLASS).join(&p.path).exists();
        return (!present && p.hotplug).then(|| {
            format!(
                "{} = {:?} does not exist now (hotplug = true: the service waits for it)",
                p.key, p.path
            )
        });
    }
    if !Path::new(&p.path).exists() {
        return p.hotplug.then(|| {
            format!(
                "{} = {:?} does not exist now (hotplug = true: the service waits for it)",
                p.key, p.path
            )
        });
    }
    let rw = nix::unistd::AccessFlags::R_OK | nix::unistd::AccessFlags::W_OK;
    nix::unistd::access(Path::new(&p.path), rw).err().map(|e| {
        format!(
            "{} = {:?} cannot be opened for reading and writing by this user ({e}); the service's user must be in the port's group (ls -l {})",
            p.key, p.path, p.path
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(key: &str, path: &str, hotplug: bool) -> PortSpec {
        PortSpec {
            key: key.into(),
            path: path.into(),
            interface: false,
            hotplug,
            line: 3,
            column: 1,
        }
    }

    #[test]
    fn a_device_reached_through_a_symlink_is_the_same_port() {
        let dir = tempfile::tempdir().unwrap();
        let link = dir.path().join("metrolog-li80");
        std::os::unix::fs::symlink("/dev/null", &link).unwrap();
        let ports = [
            spec("[interferometer] port", "/dev/null", false),
            spec("[capball] port", link.to_str().unwrap(), false),
        ];
        let found = shared_ports(&ports);
        assert_eq!(found.len(), 1, "{found:?}");
        assert_eq!(found[0].0.key, "[capball] port");
        assert!(found[0].1.contains("both /dev/null"), "{}", found[0].1);
        assert!(missing_ports(&ports).is_empty());
    }

    #[test]
    fn a_regular_file_is_no_port_and_a_hotplug_one_may_be_absent() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("file");
        std::fs::write(&file, "").unwrap();
        let absent = dir.path().join("absent");
        let ports = [
            spec("[psd] port", file.to_str().unwrap(), false),
            spec("[capball] port", absent.to_str().unwrap(), true),
        ];
        let found = missing_ports(&ports);
        assert_eq!(found.len(), 1, "{found:?}");
        assert!(found[0].1.contains("is not a device"), "{}", found[0].1);
        let notes = port_notes(&ports);
        assert!(
            notes.iter().any(|n| n.contains("hotplug = true")),
            "{notes:?}"
        );
    }
}
