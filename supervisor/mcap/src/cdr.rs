//! `sensor_msgs/msg/JointState` in ROS 2's CDR (XCDR1, little endian): what ros2 bag, Foxglove and
//! PlotJuggler decode with the message definition below and no schema of ours.

/// The `ros2msg` definition of `sensor_msgs/msg/JointState` with its dependencies, as rosbag2
/// writes it into an MCAP schema.
pub const JOINT_STATE_MSGDEF: &str = "std_msgs/Header header
string[] name
float64[] position
float64[] velocity
float64[] effort
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
";

/// A CDR buffer: the 4-byte encapsulation header (CDR, little endian), then the fields, each
/// aligned to its size counted from the end of that header.
struct Cdr(Vec<u8>);

impl Cdr {
    fn new() -> Self {
        // A joint state is 156 bytes: one allocation.
        let mut v = Vec::with_capacity(256);
        v.extend([0x00, 0x01, 0x00, 0x00]);
        Cdr(v)
    }
    fn align(&mut self, n: usize) {
        while !(self.0.len() - 4).is_multiple_of(n) {
            self.0.push(0);
        }
    }
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.0.extend_from_slice(s.as_bytes());
        self.0.push(0);
    }
    fn f64s(&mut self, v: &[f64]) {
        self.u32(v.len() as u32);
        for x in v {
            self.align(8);
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
}

/// The three joints' names, as the JointState messages carry them.
pub const JOINTS: [&str; 3] = ["joint_1", "joint_2", "joint_3"];

/// One JointState: stamped `t_ns` (ns), positions q (rad), velocities q̇ (rad/s) and efforts
/// τ (N m) of the three joints.
pub fn joint_state(t_ns: u64, q: &[f64; 3], qd: &[f64; 3], tau: &[f64; 3]) -> Vec<u8> {
    let mut c = Cdr::new();
    c.u32((t_ns / 1_000_000_000) as u32); // int32 sec (a run is far shorter than 68 years)
    c.u32((t_ns % 1_000_000_000) as u32);
    c.string("base");
    c.u32(JOINTS.len() as u32);
    for j in JOINTS {
        c.string(j);
    }
    c.f64s(q);
    c.f64s(qd);
    c.f64s(tau);
    c.0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The layout by hand: header, stamp, frame id, names, then each array's count and its
    /// doubles aligned to 8 counted after the encapsulation header.
    #[test]
    fn a_joint_state_is_laid_out_as_cdr() {
        let b = joint_state(1_500_000_300, &[1.0, 2.0, 3.0], &[0.0; 3], &[-1.0; 3]);
        assert_eq!(&b[..4], &[0, 1, 0, 0]);
        assert_eq!(u32::from_le_bytes(b[4..8].try_into().unwrap()), 1);
        assert_eq!(
            u32::from_le_bytes(b[8..12].try_into().unwrap()),
            500_000_300
        );
        assert_eq!(
            u32::from_le_bytes(b[12..16].try_into().unwrap()),
            5,
            "\"base\" + NUL"
        );
        assert_eq!(&b[16..21], b"base\0");
        // names: count at 24 (after padding to 4), then "joint_1\0" (len 8) ×3 → ends at 64.
        assert_eq!(u32::from_le_bytes(b[24..28].try_into().unwrap()), 3);
        assert_eq!(&b[32..40], b"joint_1\0");
        // position: count at 64, doubles from 68 (offset 64 after the header: aligned to 8).
        assert_eq!(u32::from_le_bytes(b[64..68].try_into().unwrap()), 3);
        assert_eq!(f64::from_le_bytes(b[68..76].try_into().unwrap()), 1.0);
        assert_eq!(f64::from_le_bytes(b[84..92].try_into().unwrap()), 3.0);
        // velocity: count at 92, then 4 bytes of padding (offset 92 is not a multiple of 8).
        assert_eq!(u32::from_le_bytes(b[92..96].try_into().unwrap()), 3);
        assert_eq!(f64::from_le_bytes(b[100..108].try_into().unwrap()), 0.0);
        assert_eq!(b.len(), 100 + 24 + 4 + 4 + 24);
    }
}
