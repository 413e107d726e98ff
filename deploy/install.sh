#!/usr/bin/env bash
# Install metrolog as a systemd service on this PC (Debian/Ubuntu; run as root from the repo):
#   sudo bash deploy/install.sh
# Builds the release binary (as the invoking user when run through sudo), then installs:
#   /usr/local/bin/metrolog, /etc/systemd/system/metrolog.service,
#   /etc/udev/rules.d/99-metrolog.rules, /etc/metrolog/metrolog.toml (kept if present),
#   the system user `metrolog` (in `dialout`) and its state directory /var/lib/metrolog.
# It enables the service but starts it only with --start (edit the config and udev rules first).
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
repo="$(dirname "$here")"
start=no
[[ "${1:-}" == "--start" ]] && start=yes

if [[ $EUID -ne 0 ]]; then
    echo "install.sh: run as root (sudo bash deploy/install.sh)" >&2
    exit 1
fi

echo "== building the release binary"
target_dir="${CARGO_TARGET_DIR:-$repo/target}"
if [[ -n "${SUDO_USER:-}" && "$SUDO_USER" != root ]]; then
    sudo -u "$SUDO_USER" env CARGO_TARGET_DIR="$target_dir" bash -lc "cd '$repo' && cargo build --release -p metrolog"
else
    (cd "$repo" && CARGO_TARGET_DIR="$target_dir" cargo build --release -p metrolog)
fi

echo "== installing files"
install -D -m 0755 "$target_dir/release/metrolog" /usr/local/bin/metrolog
install -D -m 0644 "$here/metrolog.service" /etc/systemd/system/metrolog.service
install -D -m 0644 "$here/99-metrolog.rules" /etc/udev/rules.d/99-metrolog.rules
install -D -m 0644 "$repo/README.md" /usr/local/share/doc/metrolog/README.md
install -d -m 0755 /etc/metrolog
if [[ ! -e /etc/metrolog/metrolog.toml ]]; then
    install -m 0644 "$here/metrolog.toml" /etc/metrolog/metrolog.toml
    echo "   wrote /etc/metrolog/metrolog.toml (example: edit machine, ports, trajectory, transform)"
else
    echo "   kept the existing /etc/metrolog/metrolog.toml"
fi

# SocketCAN needs the host's network namespace and AF_CAN (see metrolog.service).
if grep -Eq '^[[:space:]]*socketcan[[:space:]]*=' /etc/metrolog/metrolog.toml; then
    install -D -m 0644 "$here/metrolog-socketcan.conf" /etc/systemd/system/metrolog.service.d/socketcan.conf
    echo "   SocketCAN trigger configured: installed the socketcan.conf drop-in"
else
    rm -f /etc/systemd/system/metrolog.service.d/socketcan.conf
fi

# The live view listens on TCP: the host's network namespace and AF_INET/AF_INET6, loopback
# peers only (metrolog-live.conf; docs/live-view.md).
if grep -Eq '^[[:space:]]*\[live\]' /etc/metrolog/metrolog.toml; then
    install -D -m 0644 "$here/metrolog-live.conf" /etc/systemd/system/metrolog.service.d/live.conf
    echo "   [live] configured: installed the live.conf drop-in (TCP, loopback peers only)"
else
    rm -f /etc/systemd/system/metrolog.service.d/live.conf
fi

echo "== user and state directory"
if ! id metrolog >/dev/null 2>&1; then
    useradd --system --home-dir /var/lib/metrolog --no-create-home --shell /usr/sbin/nologin \
        --groups dialout metrolog
else
    usermod -a -G dialout metrolog
fi
install -d -m 0750 -o metrolog -g metrolog /var/lib/metrolog
echo "   operators read the logs through the group metrolog: usermod -a -G metrolog,systemd-journal USER"

echo "== reloading udev and systemd"
udevadm control --reload || echo "   (udev not running; rules apply at next boot)"
udevadm trigger --subsystem-match=tty || true
systemctl daemon-reload
systemd-analyze verify /etc/systemd/system/metrolog.service || echo "   systemd-analyze verify reported the problems above"
# The same checks the service makes at every start: every mistake at once, missing ports
# (unless hotplug = true), a port given twice, unreadable files.
/usr/local/bin/metrolog run --config /etc/metrolog/metrolog.toml --check \
    || echo "   fix /etc/metrolog/metrolog.toml before starting the service"
systemctl enable metrolog.service
if [[ $start == yes ]]; then
    systemctl restart metrolog.service
    systemctl --no-pager status metrolog.service || true
else
    echo "installed. Start with: systemctl start metrolog; follow with: journalctl -fu metrolog"
fi
