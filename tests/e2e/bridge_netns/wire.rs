//! What crosses the wire between the namespaces: `bench net`'s rows, and forged, replayed and
//! other runs' datagrams refused and counted.

use super::*;

#[test]
fn bench_net_prints_its_three_rows_and_a_last_line() {
    let test = "bench_net_prints_its_three_rows_and_a_last_line";
    if not_root(test) {
        return;
    }
    if let Some(why) = Command::new("ip")
        .arg("-V")
        .output()
        .err()
        .map(|e| format!("needs `ip` (iproute2): {e}"))
    {
        skip(test, &why);
        return;
    }
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let child = Command::new(env!("CARGO_BIN_EXE_deltaloop"))
        .args(["bench", "net", "--hold-s", "1"])
        .current_dir(ROOT)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id() % 100_000;
    let o = common::finish_within(child, Duration::from_secs(60), "deltaloop bench net");
    let out = text(&o.stdout);
    assert!(o.status.success(), "{}{out}", text(&o.stderr));
    // Each row's p50 is finite and positive.
    let (mut bridge_answered, mut direct_answered) = (true, true);
    for path in ["UDP ping-pong", "direct", "relay", "one host"] {
        let row = out
            .lines()
            .find(|l| l.starts_with(&format!("| {path}")))
            .unwrap_or_else(|| panic!("no row {path}: {out}"));
        let p50: f64 = row
            .split(" | ")
            .nth(1)
            .unwrap()
            .split(" / ")
            .next()
            .unwrap()
            .parse()
            .unwrap();
        // The realtime runs' rows end with how each ended: a typed status, whatever the host did
        // (a row's misses and status depend on timing: not judged here). A run that faulted before
        // any reply came back (the host held the far side for its first 100 ticks) has no round
        // trip: only a run that ended ok must have measured one.
        let answered = if path == "UDP ping-pong" {
            true
        } else {
            let status = row
                .trim_end_matches(" |")
                .rsplit_once(" (")
                .and_then(|(_, s)| s.strip_suffix(')'))
                .unwrap_or_else(|| panic!("no status: {row}"));
            let status: RunStatus = serde_json::from_value(status.into())
                .unwrap_or_else(|e| panic!("{status:?} is not a run status ({e}): {row}"));
            status == RunStatus::Ok
        };
        assert!(p50.is_finite() && p50 >= 0.0, "{row}");
        assert!(p50 > 0.0 || !answered, "{row}");
        if path == "relay" {
            bridge_answered = answered;
        }
        if path == "direct" {
            direct_answered = answered;
        }
    }
    let last = out.lines().last().unwrap();
    let kv: std::collections::HashMap<&str, f64> = last
        .split(' ')
        .map(|f| {
            let (k, v) = f.split_once('=').unwrap();
            (k, v.parse().unwrap())
        })
        .collect();
    for k in [
        "udp_p50_us",
        "direct_p50_us",
        "bridge_p50_us",
        "one_host_p50_us",
        "bridge_over_udp",
        "direct_over_udp",
    ] {
        // A run's figures are 0 when it faulted before any reply (see above).
        let measured = (bridge_answered || !k.starts_with("bridge"))
            && (direct_answered || !k.starts_with("direct"));
        assert!(kv[k].is_finite() && kv[k] >= 0.0, "{k}: {last}");
        assert!(kv[k] > 0.0 || !measured, "{k}: {last}");
    }
    for k in ["direct_miss_ratio", "one_host_miss_ratio"] {
        assert!((0.0..=1.0).contains(&kv[k]), "{k}: {last}");
    }
    // Nothing left: neither namespace of the command (named by its pid).
    let ns = text(
        &Command::new("ip")
            .args(["netns", "list"])
            .output()
            .unwrap()
            .stdout,
    );
    let mine = [format!("dlb{pid}0a"), format!("dlb{pid}0b")];
    assert!(
        !ns.lines()
            .any(|l| mine.iter().any(|m| l.split(' ').next() == Some(m))),
        "{ns}"
    );
}

/// An attacker on the far host's wire: it reads the first reply datagram the far bridge sends
/// (AF_PACKET on the far veth), then sends it again (a replay), a copy with a byte of its sealed
/// payload flipped (a forgery) and a copy with another session id (another run), five of each,
/// all from the far bridge's address and port (a raw socket), while the run goes on.
const ATTACKER: &str = r#"
import socket, struct, sys, time
dev, near, port = sys.argv[1], sys.argv[2], int(sys.argv[3])
cap = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.ntohs(3))
cap.bind((dev, 0))
# As long as the test waits for the run (a loaded host can hold its start up).
cap.settimeout(120)
while True:
    f = cap.recv(4096)
    if f[12:14] != b"\x08\x00" or f[14 + 9] != 17:
        continue
    ip = f[14:]
    ihl = (ip[0] & 15) * 4
    if socket.inet_ntoa(ip[16:20]) != near:
        continue
    sport, dport, ulen = struct.unpack("!HHH", ip[ihl:ihl + 6])
    payload = ip[ihl + 8:ihl + ulen]
    if dport == port and payload[:4] == b"DLB2":
        src = ip[12:16]
        break
raw = socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW)
def send(data):
    udp = struct.pack("!HHHH", sport, port, 8 + len(data), 0) + data
    iph = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0, 64, 17, 0, src, socket.inet_aton(near))
    raw.sendto(iph + udp, (near, 0))
forged = bytearray(payload); forged[30] ^= 0x40
other = bytearray(payload); other[8] ^= 1
for _ in range(5):
    send(payload); send(bytes(forged)); send(bytes(other))
    time.sleep(0.05)
print("sent", len(payload))
"#;

/// Forged, replayed and other-run datagrams injected on the wire during a realtime run across
/// the link are never applied: each is refused and counted by its reason in `summary.json`, the
/// terminal says the link refused them, and the run replays byte for byte.
#[test]
fn forged_replayed_and_other_run_datagrams_on_the_wire_are_refused_and_counted() {
    let name = "forged_replayed_and_other_run_datagrams_on_the_wire_are_refused_and_counted";
    let Some((h, _one)) = Hosts::new(name) else {
        return;
    };
    if Command::new("python3").arg("-V").output().is_err() {
        return skip(
            name,
            "needs python3 (its socket module) to play the attacker",
        );
    }
    on_a_noisy_host(name, |attempt| {
        let out = h.tmp.path().join(format!("remote-{attempt}"));
        let join = h.join(&[]);
        let run = h.run_with(
            Remote::Controller,
            &h.roomy_config(),
            &out,
            &["--mode", "realtime", "--hold-s", "3"],
        );
        let veth_b = h.net.veth_a.trim_end_matches('a').to_string() + "b";
        let attacker = h
            .cmd(
                "b",
                "python3",
                &["-c", ATTACKER, &veth_b, "10.77.0.1", "7447"],
            )
            .output()
            .unwrap();
        let (r, _j) = both(run, join, Duration::from_secs(120));
        // After the run has ended, so that a run that never sent a reply says why.
        assert!(
            attacker.status.success(),
            "attacker: {}; the run: {}",
            text(&attacker.stderr),
            text(&r.stderr)
        );
        // Whatever the host did: a typed status, every tick on disk, a byte-for-byte replay (no
        // injected datagram reached the loop), both roots empty.
        let s = summary(&out);
        let status = common::assert_every_tick_on_disk(&s, &out, "tdc");
        assert_eq!(
            r.status.success(),
            status.is_physical(),
            "{}",
            text(&r.stderr)
        );
        common::assert_replays(&out);
        h.assert_roots_empty();
        // The counts need the run to have lasted through the attack (0.25 s from the first
        // reply): judged on a run the host left alone.
        let refused = &s["timing"]["tdc"]["link_security"]["refused_datagrams"];
        let counted = ["replayed", "forged", "other_run"]
            .iter()
            .map(|r| (*r, refused[r].as_u64().unwrap_or(0)))
            .collect::<Vec<_>>();
        judge(
            common::disturbance(&s, "tdc"),
            if counted.iter().all(|(_, n)| *n == 5)
                && text(&r.stderr).contains("the link refused 0 connection(s) before")
            {
                Ok(())
            } else {
                Err(format!("refused {counted:?}: {}", text(&r.stderr)))
            },
        )
    });
}
