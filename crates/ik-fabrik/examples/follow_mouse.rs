//! A chain following a mouse-like path: an arm of named joints whose hand tracks a
//! wandering pointer frame by frame, each solve starting from the previous frame's pose
//! (a warm start, so the arm moves smoothly instead of jumping between solutions).
//!
//! Run with `cargo run --release -p sinew-ik-fabrik --example follow_mouse`.

use sinew_ik_fabrik::{DVec3, FabrikSolver};
use sinew_skeleton::ik::{
    Chain, EffectorGoal, IkProblem, IkSolver, IkState, SolveSettings, largest_rotation_change,
};
use sinew_skeleton::{GlobalPose, JointDef, Skeleton};

/// A pointer wandering over the screen (the x-y plane, 0.8 wide) the way a hand moves
/// a mouse: a slow sweep with a faster wiggle on top, sampled at 60 frames per second.
fn pointer(frame: usize) -> DVec3 {
    let t = frame as f64 / 60.0;
    DVec3::new(
        0.35 * (0.7 * t).sin() + 0.05 * (5.3 * t).sin(),
        0.45 + 0.2 * (1.1 * t).cos() + 0.04 * (7.9 * t).cos(),
        0.1,
    )
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // Shoulder at the origin, then upper arm, forearm and hand: reach 0.8.
    let arm = Skeleton::new([
        JointDef::root(DVec3::ZERO).named("shoulder"),
        JointDef::child(0, DVec3::new(0.0, 0.35, 0.0)).named("elbow"),
        JointDef::child(1, DVec3::new(0.0, 0.3, 0.0)).named("wrist"),
        JointDef::child(2, DVec3::new(0.0, 0.15, 0.0)).named("fingertip"),
    ])?;
    let chain = Chain::new(
        &arm,
        arm.joint_index("shoulder")?,
        arm.joint_index("fingertip")?,
    )?;
    let settings = SolveSettings::default();
    let mut solver = FabrikSolver::new();

    let mut pose = arm.rest_pose();
    let mut global = GlobalPose::new();
    arm.forward_kinematics(&pose, &mut global)?;

    let frames = 600;
    let (mut worst_error, mut worst_turn, mut iterations) = (0.0f64, 0.0f64, 0);
    for frame in 0..frames {
        let goals = [EffectorGoal::at(chain.effector(), pointer(frame))];
        let problem = IkProblem::new(&arm, &chain, &goals, settings);
        let before = pose.clone();
        let report = solver.solve(&problem, &mut IkState::new(&mut pose, &mut global))?;
        // How far any joint turned since the last frame: small when tracking is smooth.
        let turn = largest_rotation_change(&before, &pose, chain.joints());
        worst_error = worst_error.max(report.error);
        // The first frame moves from the rest pose to the path, a jump by design.
        if frame > 0 {
            worst_turn = worst_turn.max(turn);
        }
        iterations += report.iterations;
        if frame % 100 == 0 {
            let tip = global.positions[chain.effector()];
            println!(
                "frame {frame:3}: fingertip ({:+.3}, {:+.3}, {:+.3}), error {:.1e}, {} iterations, largest joint turn {:.3} rad",
                tip.x, tip.y, tip.z, report.error, report.iterations, turn
            );
        }
    }
    println!(
        "{frames} frames: worst error {worst_error:.1e}, {:.2} iterations per frame, largest turn between frames after the first {worst_turn:.3} rad",
        iterations as f64 / frames as f64
    );
    // The pointer never leaves the arm's reach, so every frame meets the tolerance.
    assert!(worst_error <= settings.tolerance);
    Ok(())
}
