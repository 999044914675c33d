//! Writes `scenes/data/squat.bvh`, a squat of a simple humanoid (21 joints plus five end
//! sites), to standard output:
//!
//! ```text
//! cargo run -p sinew-io --example squat_bvh > scenes/data/squat.bvh
//! ```
//!
//! Units are metres; the character stands on y = 0 facing +z. Over 2 s (61 frames at
//! 30 frames per second, the last equal to the first) the hips drop by up to
//! `DROP = 0.3` and rise again, `h(t) = DROP (1 - cos(2 pi t / 2 s)) / 2`, with no
//! horizontal motion. Each leg (thigh and shin both 0.42) keeps its ankle where it stands:
//! with `D = 0.84 - h` the hip-to-ankle distance and `a = acos(D / 0.84)`, the thigh turns
//! by `-a` about x (knee forward), the knee by `2a` and the ankle by `-a`, so the shin
//! comes back under the hip and the foot stays flat. The spine leans forward by `a / 2`,
//! and the arms swing forward by up to 80 degrees with the elbows bent by up to 30.
//! The hips use `Xposition Yposition Zposition Zrotation Xrotation Yrotation`, the spine
//! and legs `Zrotation Xrotation Yrotation`, the arms `Xrotation Yrotation Zrotation`, so
//! the file exercises two rotation orders.

use std::f64::consts::PI;
use std::fmt::Write;

/// Hip drop at the bottom of the squat (metres).
const DROP: f64 = 0.3;
/// Thigh and shin length (metres).
const LEG: f64 = 0.42;
/// Frames per second and number of frames.
const FPS: f64 = 30.0;
const FRAMES: usize = 61;

/// A joint of the hierarchy: name, offset, channel order (`None` for an end site),
/// children.
struct J {
    name: &'static str,
    offset: [f64; 3],
    order: Option<&'static str>,
    children: Vec<J>,
}

fn j(name: &'static str, offset: [f64; 3], order: &'static str, children: Vec<J>) -> J {
    J {
        name,
        offset,
        order: Some(order),
        children,
    }
}

fn end(offset: [f64; 3]) -> J {
    J {
        name: "",
        offset,
        order: None,
        children: Vec::new(),
    }
}

const ZXY: &str = "Zrotation Xrotation Yrotation";
const XYZ: &str = "Xrotation Yrotation Zrotation";

fn leg(side: &'static [&'static str; 4], x: f64) -> J {
    j(
        side[0],
        [x, -0.05, 0.0],
        ZXY,
        vec![j(
            side[1],
            [0.0, -LEG, 0.0],
            ZXY,
            vec![j(
                side[2],
                [0.0, -LEG, 0.0],
                ZXY,
                vec![j(
                    side[3],
                    [0.0, -0.06, 0.12],
                    ZXY,
                    vec![end([0.0, 0.0, 0.05])],
                )],
            )],
        )],
    )
}

fn arm(side: &'static [&'static str; 4], x: f64) -> J {
    j(
        side[0],
        [0.05 * x, 0.15, 0.0],
        XYZ,
        vec![j(
            side[1],
            [0.12 * x, 0.0, 0.0],
            XYZ,
            vec![j(
                side[2],
                [0.28 * x, 0.0, 0.0],
                XYZ,
                vec![j(
                    side[3],
                    [0.25 * x, 0.0, 0.0],
                    XYZ,
                    vec![end([0.08 * x, 0.0, 0.0])],
                )],
            )],
        )],
    )
}

fn humanoid() -> J {
    let left_leg = &["LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToe"];
    let right_leg = &["RightUpLeg", "RightLeg", "RightFoot", "RightToe"];
    let left_arm = &["LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand"];
    let right_arm = &["RightShoulder", "RightArm", "RightForeArm", "RightHand"];
    J {
        name: "Hips",
        offset: [0.0, 0.0, 0.0],
        order: Some("Xposition Yposition Zposition Zrotation Xrotation Yrotation"),
        children: vec![
            j(
                "Spine",
                [0.0, 0.1, 0.0],
                ZXY,
                vec![j(
                    "Chest",
                    [0.0, 0.2, 0.0],
                    ZXY,
                    vec![
                        j(
                            "Neck",
                            [0.0, 0.2, 0.0],
                            ZXY,
                            vec![j("Head", [0.0, 0.1, 0.0], ZXY, vec![end([0.0, 0.15, 0.0])])],
                        ),
                        arm(left_arm, 1.0),
                        arm(right_arm, -1.0),
                    ],
                )],
            ),
            leg(left_leg, 0.1),
            leg(right_leg, -0.1),
        ],
    }
}

fn write_joint(out: &mut String, joint: &J, depth: usize, root: bool) {
    let pad = "  ".repeat(depth);
    let [x, y, z] = joint.offset;
    match joint.order {
        Some(order) => {
            let kind = if root { "ROOT" } else { "JOINT" };
            let count = order.split_whitespace().count();
            let _ = writeln!(out, "{pad}{kind} {}", joint.name);
            let _ = writeln!(out, "{pad}{{");
            let _ = writeln!(out, "{pad}  OFFSET {x:.6} {y:.6} {z:.6}");
            let _ = writeln!(out, "{pad}  CHANNELS {count} {order}");
            for c in &joint.children {
                write_joint(out, c, depth + 1, false);
            }
            let _ = writeln!(out, "{pad}}}");
        }
        None => {
            let _ = writeln!(out, "{pad}End Site");
            let _ = writeln!(out, "{pad}{{");
            let _ = writeln!(out, "{pad}  OFFSET {x:.6} {y:.6} {z:.6}");
            let _ = writeln!(out, "{pad}}}");
        }
    }
}

/// The channel values of every joint at time `t`, in file (depth-first) order.
fn frame(joint: &J, t: f64, out: &mut Vec<f64>) {
    let phase = 0.5 * (1.0 - (2.0 * PI * t / 2.0).cos());
    let h = DROP * phase;
    let a = ((2.0 * LEG - h) / (2.0 * LEG))
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    let rot = |z: f64, x: f64, y: f64| [z, x, y];
    let values: Option<Vec<f64>> = match joint.name {
        "Hips" => Some(vec![0.0, 0.95 - h, 0.0, 0.0, 0.0, 0.0]),
        "Spine" => Some(rot(0.0, 0.5 * a, 0.0).to_vec()),
        "LeftUpLeg" | "RightUpLeg" => Some(rot(0.0, -a, 0.0).to_vec()),
        "LeftLeg" | "RightLeg" => Some(rot(0.0, 2.0 * a, 0.0).to_vec()),
        "LeftFoot" | "RightFoot" => Some(rot(0.0, -a, 0.0).to_vec()),
        // Arms (X Y Z order): swing forward about y, elbows bend about y too.
        "LeftArm" => Some(vec![0.0, -80.0 * phase, 0.0]),
        "RightArm" => Some(vec![0.0, 80.0 * phase, 0.0]),
        "LeftForeArm" => Some(vec![0.0, -30.0 * phase, 0.0]),
        "RightForeArm" => Some(vec![0.0, 30.0 * phase, 0.0]),
        "" => None,
        _ => Some(vec![0.0; 3]),
    };
    if let Some(v) = values {
        out.extend(v);
    }
    for c in &joint.children {
        frame(c, t, out);
    }
}

fn main() {
    let body = humanoid();
    let mut out = String::from("HIERARCHY\n");
    write_joint(&mut out, &body, 0, true);
    let _ = writeln!(out, "MOTION");
    let _ = writeln!(out, "Frames: {FRAMES}");
    let _ = writeln!(out, "Frame Time: {:.8}", 1.0 / FPS);
    for f in 0..FRAMES {
        let mut values = Vec::new();
        frame(&body, f as f64 / FPS, &mut values);
        let line: Vec<String> = values.iter().map(|v| format!("{v:.6}")).collect();
        let _ = writeln!(out, "{}", line.join(" "));
    }
    print!("{out}");
}
