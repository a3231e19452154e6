//! The Delta robot in 3D: a `foxglove.SceneUpdate` (JSON) per tick, drawn from the plant's
//! forward kinematics: the base, the three upper arms, the parallelogram forearms, the platform,
//! the payload once it is on; and the reference path, once. Frame `base`: the robot's base frame,
//! z up, m.

use deltaloop_model::{DeltaRobot, Vec3};
use serde_json::{Value, json};

/// The JSON schema of `foxglove.SceneUpdate`, as far as these messages use it.
pub const SCENE_UPDATE_SCHEMA: &str = r#"{"title":"foxglove.SceneUpdate","type":"object","properties":{"deletions":{"type":"array"},"entities":{"type":"array","items":{"type":"object","properties":{"timestamp":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_id":{"type":"string"},"id":{"type":"string"},"lifetime":{"type":"object","properties":{"sec":{"type":"integer"},"nsec":{"type":"integer"}}},"frame_locked":{"type":"boolean"},"lines":{"type":"array"},"spheres":{"type":"array"}}}}}}"#;

/// Half the width of a forearm parallelogram, m (drawn only: the model's forearm is one rod).
const HALF_PARALLELOGRAM_M: f64 = 0.02;

fn point(p: &Vec3) -> Value {
    json!({"x": p[0], "y": p[1], "z": p[2]})
}

fn stamp(t_ns: u64) -> Value {
    json!({"sec": t_ns / 1_000_000_000, "nsec": t_ns % 1_000_000_000})
}

/// A line primitive: `kind` 0 strip, 1 loop, 2 list (pairs); `rgba` 0..1.
fn line(kind: u8, points: &[Vec3], thickness: f64, rgba: [f64; 4]) -> Value {
    json!({
        "type": kind,
        "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
        "thickness": thickness,
        "scale_invariant": true,
        "points": points.iter().map(point).collect::<Vec<_>>(),
        "color": {"r": rgba[0], "g": rgba[1], "b": rgba[2], "a": rgba[3]},
        "colors": [],
        "indices": [],
    })
}

fn entity(t_ns: u64, id: &str, lines: Vec<Value>, spheres: Vec<Value>) -> Value {
    json!({
        "timestamp": stamp(t_ns),
        "frame_id": "base",
        "id": id,
        "lifetime": {"sec": 0, "nsec": 0},
        "frame_locked": false,
        "metadata": [],
        "arrows": [], "cubes": [], "cylinders": [], "cones": [], "triangles": [], "texts": [], "models": [],
        "lines": lines,
        "spheres": spheres,
    })
}

/// The robot at joint angles `q` (rad) at time `t_ns`; `payload_kg` drawn on the platform when
/// it is not 0. None where the angles do not assemble (the FK has no solution).
pub fn robot(robot: &DeltaRobot, t_ns: u64, q: &Vec3, payload_kg: f64) -> Option<Value> {
    let pose = robot.pose(q).ok()?;
    let p = robot.params();
    let axes: [Vec3; 3] = std::array::from_fn(|i| {
        let phi = p.phi_deg[i].to_radians();
        Vec3::new(phi.cos(), phi.sin(), 0.0)
    });
    let base: Vec<Vec3> = axes.iter().map(|u| u * p.base_radius).collect();
    let joints: Vec<Vec3> = axes
        .iter()
        .map(|u| pose.x + u * p.platform_radius)
        .collect();
    let elbows: Vec<Vec3> = (0..3).map(|i| joints[i] - pose.d[i]).collect();
    let (mut arms, mut rods) = (Vec::new(), Vec::new());
    for i in 0..3 {
        arms.extend([base[i], elbows[i]]);
        // The parallelogram: two rods, offset along the motor axis.
        let w = Vec3::new(-axes[i][1], axes[i][0], 0.0) * HALF_PARALLELOGRAM_M;
        rods.extend([elbows[i] + w, joints[i] + w, elbows[i] - w, joints[i] - w]);
    }
    let grey = [0.55, 0.57, 0.6, 1.0];
    let lines = vec![
        line(1, &base, 4.0, grey),
        line(2, &arms, 6.0, [0.12, 0.47, 0.71, 1.0]),
        line(2, &rods, 3.0, [1.0, 0.5, 0.05, 1.0]),
        line(1, &joints, 4.0, grey),
    ];
    let mut spheres: Vec<Value> = elbows
        .iter()
        .map(|e| sphere(e, 0.012, [0.12, 0.47, 0.71, 1.0]))
        .collect();
    if payload_kg > 0.0 {
        // A sphere of the payload's mass at steel's density, at least 2 cm across.
        let r = (3.0 * payload_kg / (4.0 * std::f64::consts::PI * 7850.0))
            .cbrt()
            .max(0.01);
        spheres.push(sphere(
            &(pose.x - Vec3::new(0.0, 0.0, r)),
            r,
            [0.84, 0.15, 0.16, 1.0],
        ));
    }
    Some(json!({"deletions": [], "entities": [entity(t_ns, "delta", lines, spheres)]}))
}

fn sphere(c: &Vec3, r: f64, rgba: [f64; 4]) -> Value {
    json!({
        "pose": {"position": point(c), "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
        "size": {"x": 2.0 * r, "y": 2.0 * r, "z": 2.0 * r},
        "color": {"r": rgba[0], "g": rgba[1], "b": rgba[2], "a": rgba[3]},
    })
}

/// The reference path in task space (m), drawn once at t = 0 and kept.
pub fn path(points: &[Vec3]) -> Value {
    json!({"deletions": [], "entities": [entity(0, "reference", vec![line(0, points, 2.0, [0.17, 0.63, 0.17, 0.8])], vec![])]})
}
