//! One DDS participant as a ROS 2 participant: its domain and discovery range resolved as ROS 2
//! resolves them, its writers and readers under ROS topic names, and its nodes announced on
//! `ros_discovery_info` (what `ros2 node list` reads).

use crate::msg::{
    Gid16, Gid24, NodeEntitiesInfo, PARTICIPANT_ENTITIES_INFO, ParticipantEntitiesInfo, RosType,
};
use anyhow::{Context, Result, bail};
use deltaloop_config::{Ros2Distro, Ros2Range, Ros2Section};
use rustdds::no_key::{DataReader, DataWriter};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{
    CDRDeserializerAdapter, CDRSerializerAdapter, DomainParticipant, DomainParticipantBuilder,
    GUID, QosPolicies, QosPolicyBuilder, RTPSEntity, TopicKind,
};
use serde::Serialize;
use serde::de::DeserializeOwned;
use std::net::Ipv4Addr;
use std::sync::Mutex;

/// A writer of ROS 2 message `T`.
pub type Writer<T> = DataWriter<T, CDRSerializerAdapter<T>>;
/// A reader of ROS 2 message `T`.
pub type Reader<T> = DataReader<T, CDRDeserializerAdapter<T>>;

/// Where deltaloop meets ROS 2: `[ros2]` with ROS 2's environment applied.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    pub domain: u16,
    pub range: Ros2Range,
    pub section: Ros2Section,
}

impl Settings {
    /// `[ros2]` first, then ROS 2's own variables (`ROS_DOMAIN_ID`, `ROS_AUTOMATIC_DISCOVERY_RANGE`,
    /// Humble's `ROS_LOCALHOST_ONLY`), then this host only. `env` reads a variable.
    pub fn resolve(section: &Ros2Section, env: impl Fn(&str) -> Option<String>) -> Result<Self> {
        let set = |v: &str| env(v).filter(|s| !s.trim().is_empty());
        let domain = match (section.domain, set("ROS_DOMAIN_ID")) {
            (Some(d), _) => d,
            (None, Some(v)) => match v.trim().parse::<u16>() {
                Ok(d) if d <= 232 => d,
                _ => bail!(
                    "ROS_DOMAIN_ID = {v:?}: allowed 0..=232 (or unset, and [ros2] domain in the config)"
                ),
            },
            (None, None) => 0,
        };
        let range = match (section.range, set("ROS_AUTOMATIC_DISCOVERY_RANGE")) {
            (Some(r), _) => r,
            (None, Some(v)) => match v.trim() {
                "LOCALHOST" => Ros2Range::Localhost,
                "SUBNET" | "SYSTEM_DEFAULT" => Ros2Range::Subnet,
                _ => bail!(
                    "ROS_AUTOMATIC_DISCOVERY_RANGE = {v:?}: allowed LOCALHOST, SUBNET or SYSTEM_DEFAULT (OFF would leave deltaloop unseen)"
                ),
            },
            (None, None) if set("ROS_LOCALHOST_ONLY").as_deref() == Some("0") => Ros2Range::Subnet,
            (None, None) => Ros2Range::Localhost,
        };
        Ok(Self {
            domain,
            range,
            section: section.clone(),
        })
    }

    /// Domain `domain`, this host only, the section's defaults (the bench's and tests' own
    /// participants).
    pub fn localhost(domain: u16) -> Self {
        Self {
            domain,
            range: Ros2Range::Localhost,
            section: Ros2Section::default(),
        }
    }

    /// A run's `[ros2]` (its defaults if none) with this process's environment.
    pub fn of_run(cfg: &deltaloop_config::RunConfig) -> Result<Self> {
        Self::resolve(&cfg.ros2.clone().unwrap_or_default(), |v| {
            std::env::var(v).ok()
        })
    }

    /// Where discovery reaches, in words.
    pub fn reach(&self) -> &'static str {
        match self.range {
            Ros2Range::Localhost => "this host only",
            Ros2Range::Subnet => "the local networks",
        }
    }

    /// The warning line for a range beyond this host, if it is one.
    pub fn warning(&self) -> Option<String> {
        (self.range == Ros2Range::Subnet).then(|| {
            format!(
                "warning: ROS 2 discovery on the local networks (domain {}): DDS without DDS-Security authenticates no one, so anyone there can read this run{}",
                self.domain, ", and a node there can command the robot with --controller ros2"
            )
        })
    }

    /// `/<namespace>/<law>/<leaf>` as a DDS topic name: the law's `-` written `_` (ROS names
    /// allow no hyphen).
    pub fn law_topic(&self, law: &str, leaf: &str) -> String {
        format!(
            "/{}/{}/{leaf}",
            self.section.namespace,
            law.replace('-', "_")
        )
    }
}

/// The node of `--controller ros2`'s robot (the `deltaloop-ros2-robot` process): its topics
/// belong to it, and the run's terminal names it.
pub const ROBOT_NODE: &str = "deltaloop_robot";

/// What the robot of `--controller ros2` waits for before tick 0, in words (the robot's log and
/// the run's terminal).
pub fn robot_waiting_line(settings: &Settings) -> String {
    let s = &settings.section;
    format!(
        "waiting up to {} s for a ROS 2 node that reads {} and writes {} (domain {}, {}) before tick 0",
        s.wait_s,
        s.state_topic,
        s.command_topic,
        settings.domain,
        settings.reach()
    )
}

/// A ROS topic name (`/a/b`) as its DDS topic (`rt/a/b`).
pub fn dds_topic(ros_name: &str) -> String {
    format!("rt/{}", ros_name.trim_start_matches('/'))
}

/// The QoS of deltaloop's endpoints: `reliability`, `durability`, the last `depth` kept.
fn qos(reliability: Reliability, durability: Durability, depth: i32) -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(reliability)
        .durability(durability)
        .history(History::KeepLast { depth })
        .build()
}

/// Reliable that never blocks the writer: a full send window drops the sample at once (`write`
/// says WouldBlock).
const RELIABLE: Reliability = Reliability::Reliable {
    max_blocking_time: rustdds::Duration::ZERO,
};

/// Reliable and volatile.
pub fn reliable(depth: i32) -> QosPolicies {
    qos(RELIABLE, Durability::Volatile, depth)
}

/// Reliable and transient local: a reader that joins later gets the last `depth`.
pub fn latched(depth: i32) -> QosPolicies {
    qos(RELIABLE, Durability::TransientLocal, depth)
}

/// Best effort and volatile.
pub fn best_effort(depth: i32) -> QosPolicies {
    qos(Reliability::BestEffort, Durability::Volatile, depth)
}

/// What discovery has matched to a writer and a reader: the remote readers of the writer's
/// topic and the remote writers of the reader's.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Matched {
    pub readers: Vec<GUID>,
    pub writers: Vec<GUID>,
}

impl Matched {
    /// A reader and a writer of one participant (one node's pair), if there is one.
    pub fn pair(&self) -> Option<(GUID, GUID)> {
        self.readers.iter().find_map(|r| {
            let w = self.writers.iter().find(|w| w.prefix == r.prefix)?;
            Some((*r, *w))
        })
    }

    /// Files one match (`change` > 0) or unmatch (`change` < 0) of `remote` in `list`.
    fn file(list: &mut Vec<GUID>, remote: GUID, change: i32) {
        if change > 0 && !list.contains(&remote) {
            list.push(remote);
        } else if change < 0 {
            list.retain(|g| *g != remote);
        }
    }
}

/// Waits until one participant has both a reader matched to `writer` and a writer matched to
/// `reader` (DDS discovery), or `timeout`; what matched by then.
pub fn wait_matched<W, R>(
    writer: &Writer<W>,
    reader: &Reader<R>,
    timeout: std::time::Duration,
) -> Matched
where
    W: Serialize,
    R: DeserializeOwned + 'static,
{
    use rustdds::{DataReaderStatus, DataWriterStatus, StatusEvented};
    let until = std::time::Instant::now() + timeout;
    let mut m = Matched::default();
    loop {
        while let Some(s) = reader.try_recv_status() {
            if let DataReaderStatus::SubscriptionMatched {
                current, writer, ..
            } = s
            {
                Matched::file(&mut m.writers, writer, current.count_change());
            }
        }
        while let Some(s) = writer.try_recv_status() {
            if let DataWriterStatus::PublicationMatched {
                current, reader, ..
            } = s
            {
                Matched::file(&mut m.readers, reader, current.count_change());
            }
        }
        if m.pair().is_some() || std::time::Instant::now() >= until {
            return m;
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
}

/// This process's UDP sockets (IPv4 or IPv6), by descriptor.
pub fn udp_sockets() -> Vec<i32> {
    let Ok(dir) = std::fs::read_dir("/proc/self/fd") else {
        return Vec::new();
    };
    let int = |fd: i32, opt: i32| {
        let mut v: libc::c_int = 0;
        let mut len = size_of::<libc::c_int>() as libc::socklen_t;
        // SAFETY: getsockopt writes at most `len` bytes into `v`, which we own.
        let rc =
            unsafe { libc::getsockopt(fd, libc::SOL_SOCKET, opt, (&raw mut v).cast(), &mut len) };
        (rc == 0).then_some(v)
    };
    dir.filter_map(|e| e.ok()?.file_name().to_str()?.parse::<i32>().ok())
        .filter(|fd| {
            int(*fd, libc::SO_TYPE) == Some(libc::SOCK_DGRAM)
                && matches!(
                    int(*fd, libc::SO_DOMAIN),
                    Some(libc::AF_INET | libc::AF_INET6)
                )
        })
        .collect()
}

/// Binds each socket to the loopback interface (SO_BINDTODEVICE): datagrams that come in on
/// another interface never reach it, and it sends through `lo` only.
pub fn pin_to_loopback(fds: &[i32]) -> Result<()> {
    const LO: &[u8] = b"lo\0";
    for fd in fds {
        // SAFETY: the option value is LO's bytes, its length passed with it.
        let rc = unsafe {
            libc::setsockopt(
                *fd,
                libc::SOL_SOCKET,
                libc::SO_BINDTODEVICE,
                LO.as_ptr().cast(),
                LO.len() as libc::socklen_t,
            )
        };
        if rc != 0 {
            bail!(
                "SO_BINDTODEVICE lo on a DDS socket: {}",
                std::io::Error::last_os_error()
            );
        }
    }
    Ok(())
}

/// The interface a socket is bound to (SO_BINDTODEVICE), if any.
pub fn bound_device(fd: i32) -> Option<String> {
    let mut buf = [0u8; 16];
    let mut len = buf.len() as libc::socklen_t;
    // SAFETY: getsockopt writes at most `len` bytes into `buf`, which we own.
    let rc = unsafe {
        libc::getsockopt(
            fd,
            libc::SOL_SOCKET,
            libc::SO_BINDTODEVICE,
            buf.as_mut_ptr().cast(),
            &mut len,
        )
    };
    let name = &buf[..(len as usize).min(buf.len())];
    let name = name.split(|b| *b == 0).next().unwrap_or_default();
    (rc == 0 && !name.is_empty()).then(|| String::from_utf8_lossy(name).into_owned())
}

/// A reader that blocks until RustDDS notifies a sample (through mio), its events allocated once.
pub struct Waiting<T> {
    pub reader: Reader<T>,
    poll: rustdds::mio1::Poll,
    events: rustdds::mio1::Events,
}

impl<T: DeserializeOwned + 'static> Waiting<T> {
    pub fn new(mut reader: Reader<T>) -> Result<Self> {
        use rustdds::mio1::{Events, Interest, Poll, Token};
        let poll = Poll::new().context("mio poll")?;
        poll.registry()
            .register(&mut reader, Token(0), Interest::READABLE)
            .context("register a DDS reader")?;
        Ok(Self {
            reader,
            poll,
            events: Events::with_capacity(4),
        })
    }

    /// Blocks until a sample may have come, or `timeout` (a signal may end it sooner).
    pub fn wait(&mut self, timeout: std::time::Duration) {
        let _ = self.poll.poll(&mut self.events, Some(timeout));
    }
}

/// Drops what it holds on a thread of its own and waits for that at most `limit`: the drop of a
/// participant waits for its discovery thread, which a flood of announcements keeps busy for
/// minutes. Past the limit the drop goes on unwaited for, and the process's exit ends it.
pub struct DropWithin<T: Send + 'static> {
    inner: Option<T>,
    limit: std::time::Duration,
}

impl<T: Send + 'static> DropWithin<T> {
    pub fn new(inner: T, limit: std::time::Duration) -> Self {
        Self {
            inner: Some(inner),
            limit,
        }
    }

    pub fn get(&self) -> &T {
        self.inner.as_ref().expect("held until dropped")
    }
}

impl<T: Send + 'static> Drop for DropWithin<T> {
    fn drop(&mut self) {
        let Some(inner) = self.inner.take() else {
            return;
        };
        let (done, dropped) = std::sync::mpsc::channel();
        let spawned = std::thread::Builder::new()
            .name("dds-drop".into())
            .spawn(move || {
                drop(inner);
                let _ = done.send(());
            });
        if spawned.is_ok() && dropped.recv_timeout(self.limit).is_err() {
            eprintln!(
                "ROS 2: DDS did not close within {:.1} s (discovery busy); it ends with the process",
                self.limit.as_secs_f64()
            );
        }
    }
}

/// A node's endpoints, as `ros_discovery_info` lists them.
#[derive(Clone, Debug, Default)]
struct NodeInfo {
    name: String,
    readers: Vec<GUID>,
    writers: Vec<GUID>,
}

/// The graph writer: Humble's gids or Jazzy's.
enum GraphWriter {
    Humble(Writer<ParticipantEntitiesInfo<Gid24>>),
    Jazzy(Writer<ParticipantEntitiesInfo<Gid16>>),
}

/// One DDS participant with its ROS 2 nodes.
pub struct Participant {
    pub settings: Settings,
    dp: DomainParticipant,
    publisher: rustdds::Publisher,
    subscriber: rustdds::Subscriber,
    graph: GraphWriter,
    nodes: Mutex<Vec<NodeInfo>>,
}

impl<T: RosType> RosType for ParticipantEntitiesInfo<T> {
    const DDS_TYPE: &'static str = PARTICIPANT_ENTITIES_INFO;
}

impl Participant {
    /// Joins domain `settings.domain`, its discovery pinned to loopback unless the range is the
    /// subnet.
    pub fn join(settings: Settings) -> Result<Self> {
        let b = DomainParticipantBuilder::new(settings.domain);
        let b = match settings.range {
            Ros2Range::Localhost => b.with_only_networks([Ipv4Addr::LOCALHOST]),
            Ros2Range::Subnet => b,
        };
        let before = udp_sockets();
        let dp = b
            .build()
            .with_context(|| format!("cannot join DDS domain {}", settings.domain))?;
        if settings.range == Ros2Range::Localhost {
            // RustDDS binds its sockets to the wildcard address whatever the networks it is
            // told to use: bound to `lo`, they neither hear nor send on any other interface.
            let new: Vec<i32> = udp_sockets()
                .into_iter()
                .filter(|fd| !before.contains(fd))
                .collect();
            pin_to_loopback(&new).with_context(|| {
                format!(
                    "cannot keep DDS on this host (domain {}); [ros2] range = \"subnet\" would reach the local networks",
                    settings.domain
                )
            })?;
        }
        let qos = reliable(10);
        let publisher = dp.create_publisher(&qos).context("DDS publisher")?;
        let subscriber = dp.create_subscriber(&qos).context("DDS subscriber")?;
        let graph_qos = latched(1);
        let topic = dp
            .create_topic(
                "ros_discovery_info".into(),
                PARTICIPANT_ENTITIES_INFO.into(),
                &graph_qos,
                TopicKind::NoKey,
            )
            .context("the topic ros_discovery_info")?;
        let graph = match settings.section.distro {
            Ros2Distro::Humble => GraphWriter::Humble(
                publisher.create_datawriter_no_key_cdr(&topic, Some(graph_qos))?,
            ),
            Ros2Distro::Jazzy => {
                GraphWriter::Jazzy(publisher.create_datawriter_no_key_cdr(&topic, Some(graph_qos))?)
            }
        };
        Ok(Self {
            settings,
            dp,
            publisher,
            subscriber,
            graph,
            nodes: Mutex::new(Vec::new()),
        })
    }

    /// The DDS topic of ROS topic `ros_name` and message `T`.
    fn topic<T: RosType>(&self, ros_name: &str, qos: &QosPolicies) -> Result<rustdds::Topic> {
        self.dp
            .create_topic(
                dds_topic(ros_name),
                T::DDS_TYPE.into(),
                qos,
                TopicKind::NoKey,
            )
            .with_context(|| format!("the topic {ros_name}"))
    }

    /// A writer of `T` on ROS topic `ros_name` for node `node`.
    pub fn writer<T: Serialize + RosType>(
        &self,
        node: &str,
        ros_name: &str,
        qos: QosPolicies,
    ) -> Result<Writer<T>> {
        let topic = self.topic::<T>(ros_name, &qos)?;
        let w = self
            .publisher
            .create_datawriter_no_key_cdr::<T>(&topic, Some(qos))
            .with_context(|| format!("a writer on {ros_name}"))?;
        self.add(node, w.guid(), true)?;
        Ok(w)
    }

    /// A reader of `T` on ROS topic `ros_name` for node `node`.
    pub fn reader<T: DeserializeOwned + RosType + 'static>(
        &self,
        node: &str,
        ros_name: &str,
        qos: QosPolicies,
    ) -> Result<Reader<T>> {
        let topic = self.topic::<T>(ros_name, &qos)?;
        let r = self
            .subscriber
            .create_datareader_no_key_cdr::<T>(&topic, Some(qos))
            .with_context(|| format!("a reader on {ros_name}"))?;
        self.add(node, r.guid(), false)?;
        Ok(r)
    }

    /// Files an endpoint under `node` and announces the graph again.
    fn add(&self, node: &str, guid: GUID, writer: bool) -> Result<()> {
        let mut nodes = self.nodes.lock().unwrap_or_else(|e| e.into_inner());
        let i = match nodes.iter().position(|n| n.name == node) {
            Some(i) => i,
            None => {
                nodes.push(NodeInfo {
                    name: node.into(),
                    ..NodeInfo::default()
                });
                nodes.len() - 1
            }
        };
        if writer {
            nodes[i].writers.push(guid);
        } else {
            nodes[i].readers.push(guid);
        }
        self.announce(&nodes)
    }

    /// Takes endpoints out of the graph (their writers or readers are about to be dropped), so
    /// that `ros2 node info` lists no gid without an endpoint behind it, and announces it.
    pub fn retire(&self, guids: &[GUID]) -> Result<()> {
        let mut nodes = self.nodes.lock().unwrap_or_else(|e| e.into_inner());
        for n in nodes.iter_mut() {
            n.writers.retain(|g| !guids.contains(g));
            n.readers.retain(|g| !guids.contains(g));
        }
        self.announce(&nodes)
    }

    /// The gids `node` announces: (readers, writers).
    #[cfg(test)]
    pub(crate) fn announced(&self, node: &str) -> (Vec<GUID>, Vec<GUID>) {
        let nodes = self.nodes.lock().unwrap_or_else(|e| e.into_inner());
        nodes
            .iter()
            .find(|n| n.name == node)
            .map(|n| (n.readers.clone(), n.writers.clone()))
            .unwrap_or_default()
    }

    /// `ros_discovery_info`: this participant's nodes and their endpoints' gids.
    fn announce(&self, nodes: &[NodeInfo]) -> Result<()> {
        fn info<G>(
            dp: GUID,
            nodes: &[NodeInfo],
            gid: impl Fn(GUID) -> G,
        ) -> ParticipantEntitiesInfo<G> {
            ParticipantEntitiesInfo {
                gid: gid(dp),
                node_entities_info_seq: nodes
                    .iter()
                    .map(|n| NodeEntitiesInfo {
                        node_namespace: "/".into(),
                        node_name: n.name.clone(),
                        reader_gid_seq: n.readers.iter().map(|g| gid(*g)).collect(),
                        writer_gid_seq: n.writers.iter().map(|g| gid(*g)).collect(),
                    })
                    .collect(),
            }
        }
        let dp = self.dp.guid();
        let sent = match &self.graph {
            GraphWriter::Jazzy(w) => w.write(info(dp, nodes, |g| g.to_bytes()), None).is_ok(),
            GraphWriter::Humble(w) => {
                let gid = |g: GUID| {
                    let mut b = [0u8; 24];
                    b[..16].copy_from_slice(&g.to_bytes());
                    b
                };
                w.write(info(dp, nodes, gid), None).is_ok()
            }
        };
        if !sent {
            bail!("cannot announce the node on ros_discovery_info");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env<'a>(vars: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<String> + 'a {
        move |k| {
            vars.iter()
                .find(|(n, _)| *n == k)
                .map(|(_, v)| v.to_string())
        }
    }

    /// Nothing set: domain 0, this host only, no warning. The config beats the environment;
    /// the environment beats the default; a subnet says so.
    #[test]
    fn discovery_stays_on_this_host_unless_asked() {
        let s = Ros2Section::default();
        let r = Settings::resolve(&s, env(&[])).unwrap();
        assert_eq!((r.domain, r.range), (0, Ros2Range::Localhost));
        assert!(r.warning().is_none());
        let vars = [
            ("ROS_DOMAIN_ID", "42"),
            ("ROS_AUTOMATIC_DISCOVERY_RANGE", "SUBNET"),
        ];
        let r = Settings::resolve(&s, env(&vars)).unwrap();
        assert_eq!((r.domain, r.range), (42, Ros2Range::Subnet));
        assert!(r.warning().unwrap().contains("authenticates no one"));
        let pinned = Ros2Section {
            domain: Some(7),
            range: Some(Ros2Range::Localhost),
            ..s.clone()
        };
        let r = Settings::resolve(&pinned, env(&vars)).unwrap();
        assert_eq!((r.domain, r.range), (7, Ros2Range::Localhost));
        let r = Settings::resolve(&s, env(&[("ROS_LOCALHOST_ONLY", "1")])).unwrap();
        assert_eq!(r.range, Ros2Range::Localhost);
    }

    #[test]
    fn a_bad_ros_variable_is_named() {
        let s = Ros2Section::default();
        let e = Settings::resolve(&s, env(&[("ROS_DOMAIN_ID", "300")])).unwrap_err();
        assert!(e.to_string().contains("ROS_DOMAIN_ID = \"300\""), "{e}");
        let e =
            Settings::resolve(&s, env(&[("ROS_AUTOMATIC_DISCOVERY_RANGE", "OFF")])).unwrap_err();
        assert!(e.to_string().contains("allowed LOCALHOST"), "{e}");
    }

    /// On this host only, every UDP socket the participant opened is bound to `lo` (RustDDS
    /// itself binds the wildcard address).
    #[test]
    fn a_localhost_participant_hears_and_sends_on_lo_only() {
        let before = udp_sockets();
        let p = Participant::join(Settings::localhost(229)).unwrap();
        let new: Vec<i32> = udp_sockets()
            .into_iter()
            .filter(|fd| !before.contains(fd))
            .collect();
        assert!(new.len() >= 2, "the participant's sockets: {new:?}");
        for fd in &new {
            assert_eq!(bound_device(*fd).as_deref(), Some("lo"), "socket {fd}");
        }
        drop(p);
    }

    /// A law's writers leave the graph with the law: no stale gid stays announced.
    #[test]
    fn retired_endpoints_leave_the_graph() {
        let p = Participant::join(Settings::localhost(228)).unwrap();
        let a: Writer<crate::msg::Clock> = p.writer("n", "/a", best_effort(1)).unwrap();
        let b: Writer<crate::msg::Clock> = p.writer("n", "/b", best_effort(1)).unwrap();
        assert_eq!(p.announced("n").1, vec![a.guid(), b.guid()]);
        p.retire(&[a.guid()]).unwrap();
        assert_eq!(p.announced("n"), (vec![], vec![b.guid()]));
    }

    /// A guid of participant `p`, endpoint `e`.
    fn guid(p: u8, e: u8) -> GUID {
        let mut b = [p; 16];
        b[12..].copy_from_slice(&[0, 0, e, 2]);
        GUID::from_bytes(b)
    }

    /// The robot starts tick 0 only once one participant reads and writes: a reader of one
    /// node and a writer of another are no node, and an unmatched endpoint counts no more.
    #[test]
    fn a_pair_is_a_reader_and_a_writer_of_one_participant() {
        let mut m = Matched::default();
        Matched::file(&mut m.readers, guid(1, 1), 1);
        Matched::file(&mut m.writers, guid(2, 1), 1);
        assert_eq!(m.pair(), None);
        Matched::file(&mut m.writers, guid(1, 2), 1);
        assert_eq!(m.pair(), Some((guid(1, 1), guid(1, 2))));
        Matched::file(&mut m.readers, guid(1, 1), -1);
        assert_eq!(m.pair(), None);
    }

    #[test]
    fn law_topics_use_ros_names() {
        let r = Settings::resolve(&Ros2Section::default(), env(&[])).unwrap();
        assert_eq!(
            dds_topic(&r.law_topic("tdc-is-sta", "joint_states")),
            "rt/deltaloop/tdc_is_sta/joint_states"
        );
    }
}
