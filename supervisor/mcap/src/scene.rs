//! The Delta robot in 3D: a `foxglove.SceneUpdate` (JSON) per tick, drawn from the plant's
//! forward kinematics: the base, the three upper arms, the parallelogram forearms, the platform,
//! the payload once it is on; and the reference path, once. Frame `base`: the robot's base frame,
//! z up, m.

use deltaloop_model::{DeltaRobot, Vec3};
use serde::Serialize;
use serde::ser::Serializer;

/// The JSON schema of `foxglove.SceneUpdate`, as far as these messages use it.
pub const SCENE_UPDATE_SCHEMA: &str = r#"{"title":"foxglove.SceneUpdate","type":"object","properties":{"deletions":{"type":"array"},"entities":{"type":"array","items":{"type":"object","properties":{"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_id":{"type":"string"},"id":{"type":"string"},"lifetime":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_locked":{"type":"boolean"},"lines":{"type":"array"},"spheres":{"type":"array"}}}}}}"#;

/// Half the width of a forearm parallelogram, m (drawn only: the model's forearm is one rod).
const HALF_PARALLELOGRAM_M: f64 = 0.02;

// The message as plain structs serialised straight to JSON: one is written per tick while a run
// records, and a tree of `serde_json::Value`s (a map per point) cost hundreds of allocations a
// tick. Fields are in alphabetical order, the order the `Value` maps wrote them in.

/// An empty list, written `[]` (the primitives this scene does not use).
type Empty = [(); 0];

#[derive(Serialize)]
struct Xyz {
    x: f64,
    y: f64,
    z: f64,
}

impl From<&Vec3> for Xyz {
    fn from(p: &Vec3) -> Self {
        Xyz {
            x: p[0],
            y: p[1],
            z: p[2],
        }
    }
}

#[derive(Serialize)]
struct Quaternion {
    w: f64,
    x: f64,
    y: f64,
    z: f64,
}

#[derive(Serialize)]
struct Pose {
    orientation: Quaternion,
    position: Xyz,
}

impl Pose {
    /// At `p` (m), not rotated.
    fn at(p: &Vec3) -> Self {
        Pose {
            orientation: Quaternion {
                w: 1.0,
                x: 0.0,
                y: 0.0,
                z: 0.0,
            },
            position: p.into(),
        }
    }
}

#[derive(Serialize)]
struct Color {
    a: f64,
    b: f64,
    g: f64,
    r: f64,
}

impl From<[f64; 4]> for Color {
    fn from([r, g, b, a]: [f64; 4]) -> Self {
        Color { a, b, g, r }
    }
}

#[derive(Serialize)]
struct Stamp {
    nsec: u64,
    sec: u64,
}

impl Stamp {
    fn of(t_ns: u64) -> Self {
        Stamp {
            nsec: t_ns % 1_000_000_000,
            sec: t_ns / 1_000_000_000,
        }
    }
}

/// Points (m), written as `{"x", "y", "z"}` objects.
struct Points<'a>(&'a [Vec3]);

impl Serialize for Points<'_> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(self.0.iter().map(Xyz::from))
    }
}

/// A line primitive.
#[derive(Serialize)]
struct Line<'a> {
    color: Color,
    colors: Empty,
    indices: Empty,
    points: Points<'a>,
    pose: Pose,
    scale_invariant: bool,
    thickness: f64,
    /// 0 strip, 1 loop, 2 list (pairs).
    #[serde(rename = "type")]
    kind: u8,
}

/// A line primitive: `kind` 0 strip, 1 loop, 2 list (pairs); `rgba` 0..1.
fn line(kind: u8, points: &[Vec3], thickness: f64, rgba: [f64; 4]) -> Line<'_> {
    Line {
        color: rgba.into(),
        colors: [],
        indices: [],
        points: Points(points),
        pose: Pose::at(&Vec3::zeros()),
        scale_invariant: true,
        thickness,
        kind,
    }
}

#[derive(Serialize)]
struct Sphere {
    color: Color,
    pose: Pose,
    size: Xyz,
}

fn sphere(c: &Vec3, r: f64, rgba: [f64; 4]) -> Sphere {
    Sphere {
        color: rgba.into(),
        pose: Pose::at(c),
        size: Xyz {
            x: 2.0 * r,
            y: 2.0 * r,
            z: 2.0 * r,
        },
    }
}

#[derive(Serialize)]
struct Entity<'a> {
    arrows: Empty,
    cones: Empty,
    cubes: Empty,
    cylinders: Empty,
    frame_id: &'static str,
    frame_locked: bool,
    id: &'static str,
    lifetime: Stamp,
    lines: &'a [Line<'a>],
    metadata: Empty,
    models: Empty,
    spheres: &'a [Sphere],
    texts: Empty,
    timestamp: Stamp,
    triangles: Empty,
}

fn entity<'a>(
    t_ns: u64,
    id: &'static str,
    lines: &'a [Line<'a>],
    spheres: &'a [Sphere],
) -> Entity<'a> {
    Entity {
        arrows: [],
        cones: [],
        cubes: [],
        cylinders: [],
        frame_id: "base",
        frame_locked: false,
        id,
        lifetime: Stamp::of(0),
        lines,
        metadata: [],
        models: [],
        spheres,
        texts: [],
        timestamp: Stamp::of(t_ns),
        triangles: [],
    }
}

#[derive(Serialize)]
struct SceneUpdate<'a> {
    deletions: Empty,
    entities: [Entity<'a>; 1],
}

/// Draws the robot: its kinematics, the payload step, and the buffer its JSON is written in
/// (reused from tick to tick).
pub struct Painter {
    robot: DeltaRobot,
    /// From this tick on, this payload (kg) is on the platform.
    payload: Option<(u64, f64)>,
    json: Vec<u8>,
}

impl Painter {
    pub fn new(robot: DeltaRobot, payload: Option<(u64, f64)>) -> Self {
        Painter {
            robot,
            payload,
            json: Vec::new(),
        }
    }

    /// The robot at tick `k` at joint angles `q` (rad), stamped `t_ns`, as JSON; None where the
    /// angles do not assemble (the FK has no solution).
    pub fn draw(&mut self, k: u64, t_ns: u64, q: &Vec3) -> serde_json::Result<Option<&[u8]>> {
        let mass = self.payload.filter(|&(at, _)| k >= at).map_or(0.0, |p| p.1);
        self.json.clear();
        Ok(robot(&self.robot, t_ns, q, mass, &mut self.json)?.then_some(self.json.as_slice()))
    }
}

/// The robot at joint angles `q` (rad) at time `t_ns`, as JSON into `out`; `payload_kg` drawn
/// on the platform when it is not 0. False where the angles do not assemble.
fn robot(
    robot: &DeltaRobot,
    t_ns: u64,
    q: &Vec3,
    payload_kg: f64,
    out: &mut Vec<u8>,
) -> serde_json::Result<bool> {
    let Ok(pose) = robot.pose(q) else {
        return Ok(false);
    };
    let p = robot.params();
    let axes: [Vec3; 3] = std::array::from_fn(|i| {
        let phi = p.phi_deg[i].to_radians();
        Vec3::new(phi.cos(), phi.sin(), 0.0)
    });
    let base = axes.map(|u| u * p.base_radius);
    let joints = axes.map(|u| pose.x + u * p.platform_radius);
    let elbows: [Vec3; 3] = std::array::from_fn(|i| joints[i] - pose.d[i]);
    let arms: [Vec3; 6] = std::array::from_fn(|j| [base, elbows][j % 2][j / 2]);
    // The parallelogram: two rods per arm, offset along the motor axis.
    let rods: [Vec3; 12] = std::array::from_fn(|j| {
        let i = j / 4;
        let w = Vec3::new(-axes[i][1], axes[i][0], 0.0) * HALF_PARALLELOGRAM_M;
        [elbows[i] + w, joints[i] + w, elbows[i] - w, joints[i] - w][j % 4]
    });
    let grey = [0.55, 0.57, 0.6, 1.0];
    let lines = [
        line(1, &base, 4.0, grey),
        line(2, &arms, 6.0, [0.12, 0.47, 0.71, 1.0]),
        line(2, &rods, 3.0, [1.0, 0.5, 0.05, 1.0]),
        line(1, &joints, 4.0, grey),
    ];
    let blue = [0.12, 0.47, 0.71, 1.0];
    // A sphere of the payload's mass at steel's density, at least 2 cm across.
    let r = (3.0 * payload_kg / (4.0 * std::f64::consts::PI * 7850.0))
        .cbrt()
        .max(0.01);
    let spheres = [
        sphere(&elbows[0], 0.012, blue),
        sphere(&elbows[1], 0.012, blue),
        sphere(&elbows[2], 0.012, blue),
        sphere(
            &(pose.x - Vec3::new(0.0, 0.0, r)),
            r,
            [0.84, 0.15, 0.16, 1.0],
        ),
    ];
    let shown = if payload_kg > 0.0 { 4 } else { 3 };
    let scene = SceneUpdate {
        deletions: [],
        entities: [entity(t_ns, "delta", &lines, &spheres[..shown])],
    };
    serde_json::to_writer(out, &scene)?;
    Ok(true)
}

/// The reference path in task space (m), drawn once at t = 0 and kept; as JSON.
pub fn path(points: &[Vec3]) -> serde_json::Result<Vec<u8>> {
    let lines = [line(0, points, 2.0, [0.17, 0.63, 0.17, 0.8])];
    serde_json::to_vec(&SceneUpdate {
        deletions: [],
        entities: [entity(0, "reference", &lines, &[])],
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;

    fn points(line: &Value) -> Vec<[f64; 3]> {
        line["points"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| ["x", "y", "z"].map(|c| p[c].as_f64().unwrap()))
            .collect()
    }

    /// The drawn robot is the model's: base corners at the base radius, forearms of the model's
    /// length from elbow to platform joint, the platform around FK(q); the payload appears at
    /// its step tick with steel's radius.
    #[test]
    fn the_drawn_robot_is_the_models_and_the_payload_appears_at_its_step() {
        let robot = DeltaRobot::default();
        let p = robot.params().clone();
        let mut painter = Painter::new(robot.clone(), Some((10, 2.0)));
        let q = Vec3::new(0.1, 0.3, -0.2);
        let scene = |painter: &mut Painter, k| -> Value {
            serde_json::from_slice(painter.draw(k, 7_500_000_123, &q).unwrap().unwrap()).unwrap()
        };
        let before = scene(&mut painter, 9);
        let e = &before["entities"][0];
        assert_eq!(
            (e["id"].as_str(), e["frame_id"].as_str()),
            (Some("delta"), Some("base"))
        );
        assert_eq!(
            (
                e["timestamp"]["sec"].as_u64(),
                e["timestamp"]["nsec"].as_u64()
            ),
            (Some(7), Some(500_000_123))
        );
        let lines = e["lines"].as_array().unwrap();
        let n: Vec<usize> = lines.iter().map(|l| points(l).len()).collect();
        assert_eq!(n, [3, 6, 12, 3], "base, upper arms, forearm rods, platform");
        let len = |a: [f64; 3]| (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        for b in points(&lines[0]) {
            assert!(
                (len(b) - p.base_radius).abs() < 1e-12 && b[2] == 0.0,
                "{b:?}"
            );
        }
        let x = robot.pose(&q).unwrap().x;
        for (j, r) in points(&lines[3])
            .into_iter()
            .zip(points(&lines[2]).chunks(2))
        {
            assert!((len(sub(j, [x[0], x[1], x[2]])) - p.platform_radius).abs() < 1e-12);
            assert!((len(sub(r[1], r[0])) - p.forearm).abs() < 1e-9, "{r:?}");
        }
        assert_eq!(e["spheres"].as_array().unwrap().len(), 3, "elbows only");
        let after = scene(&mut painter, 10);
        let spheres = after["entities"][0]["spheres"].as_array().unwrap();
        assert_eq!(spheres.len(), 4, "the payload from its step on");
        let r = spheres[3]["size"]["x"].as_f64().unwrap() / 2.0;
        assert!((4.0 / 3.0 * std::f64::consts::PI * r.powi(3) * 7850.0 - 2.0).abs() < 1e-9);
    }
}
