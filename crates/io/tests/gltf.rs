//! The glTF skin reader on a document written here (JSON with an embedded base64 buffer
//! for the inverse bind matrices): joint order, parents, rest offsets and rotations,
//! forward kinematics of the rest pose against the scene's own node transforms, and
//! errors naming the node.

use sinew_io::gltf::{GltfError, read_gltf_skin};
use sinew_math::{DMat4, DQuat, DVec3};
use sinew_skeleton::GlobalPose;

/// Standard base64 with padding (the test's own encoder, for the data URI).
fn base64(bytes: &[u8]) -> String {
    const T: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::new();
    for chunk in bytes.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for k in 0..4 {
            if k <= chunk.len() {
                out.push(T[((n >> (18 - 6 * k)) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

/// One node: name, translation, rotation (x, y, z, w), scale, children.
struct Node {
    name: &'static str,
    t: [f64; 3],
    r: [f64; 4],
    s: [f64; 3],
    children: Vec<usize>,
}

fn node(name: &'static str, t: [f64; 3], r: [f64; 4], children: Vec<usize>) -> Node {
    Node {
        name,
        t,
        r,
        s: [1.0; 3],
        children,
    }
}

/// A unit quaternion about `axis` by `angle`, as glTF's (x, y, z, w).
fn q(axis: DVec3, angle: f64) -> [f64; 4] {
    let q = DQuat::from_axis_angle(axis.normalize(), angle);
    [q.x, q.y, q.z, q.w]
}

/// The scene: node 0 `Armature` (not a joint) above the joints; `Hips` (2) with children
/// `Spine` (3) and a plain node `Offset` (1, not a joint) that carries `LeftLeg` (4);
/// `Head` (5) under `Spine`. The skin lists its joints out of topological order.
fn scene() -> Vec<Node> {
    vec![
        node("Armature", [0.0, 0.1, -0.2], q(DVec3::Y, 0.5), vec![2]),
        node("Offset", [0.1, -0.05, 0.0], q(DVec3::Z, 0.2), vec![4]),
        node(
            "Hips",
            [0.0, 1.0, 0.0],
            q(DVec3::new(1.0, 1.0, 0.0), 0.3),
            vec![3, 1],
        ),
        node("Spine", [0.0, 0.3, 0.05], q(DVec3::X, -0.4), vec![5]),
        node("LeftLeg", [0.0, -0.45, 0.0], q(DVec3::X, 0.9), vec![]),
        node("Head", [0.0, 0.25, 0.0], [0.0, 0.0, 0.0, 1.0], vec![]),
    ]
}

const SKIN_JOINTS: [usize; 4] = [5, 4, 2, 3];

fn document(nodes: &[Node], skin_joints: &[usize]) -> String {
    let node_json: Vec<String> = nodes
        .iter()
        .map(|n| {
            format!(
                r#"{{"name":"{}","translation":[{},{},{}],"rotation":[{},{},{},{}],"scale":[{},{},{}],"children":{:?}}}"#,
                n.name, n.t[0], n.t[1], n.t[2], n.r[0], n.r[1], n.r[2], n.r[3], n.s[0], n.s[1], n.s[2], n.children
            )
            .replace(r#","children":[]"#, "")
        })
        .collect();
    // Inverse bind matrices: identity 4 x 4 per joint, f32 little-endian (the reader
    // does not need them; they make the document a complete skin).
    let mut buffer = Vec::new();
    for _ in skin_joints {
        for v in DMat4::IDENTITY.to_cols_array() {
            buffer.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
    format!(
        r#"{{
  "asset": {{"version": "2.0", "generator": "sinew test"}},
  "scene": 0,
  "scenes": [{{"nodes": [0]}}],
  "nodes": [{}],
  "skins": [{{"name": "body", "joints": {:?}, "inverseBindMatrices": 0}}],
  "accessors": [{{"bufferView": 0, "componentType": 5126, "count": {}, "type": "MAT4"}}],
  "bufferViews": [{{"buffer": 0, "byteLength": {}}}],
  "buffers": [{{"byteLength": {}, "uri": "data:application/octet-stream;base64,{}"}}]
}}"#,
        node_json.join(","),
        skin_joints,
        skin_joints.len(),
        buffer.len(),
        buffer.len(),
        base64(&buffer)
    )
}

/// World matrices of every node by glTF's rule `M = M_parent T R S`, independently of
/// the reader.
fn world(nodes: &[Node]) -> Vec<DMat4> {
    let mut parent = vec![None; nodes.len()];
    for (i, n) in nodes.iter().enumerate() {
        for &c in &n.children {
            parent[c] = Some(i);
        }
    }
    (0..nodes.len())
        .map(|mut i| {
            let mut m = DMat4::IDENTITY;
            loop {
                let n = &nodes[i];
                let local = DMat4::from_scale_rotation_translation(
                    DVec3::from(n.s),
                    DQuat::from_array(n.r),
                    DVec3::from(n.t),
                );
                m = local * m;
                match parent[i] {
                    Some(p) => i = p,
                    None => return m,
                }
            }
        })
        .collect()
}

#[test]
fn skin_joints_rest_pose_and_forward_kinematics() {
    let nodes = scene();
    let text = document(&nodes, &SKIN_JOINTS);
    let read = read_gltf_skin(text.as_bytes(), 0).unwrap();
    let s = &read.skeleton;
    // Depth-first, parents first, siblings in skin order (LeftLeg before Spine).
    let names: Vec<_> = (0..s.len()).map(|i| s.name(i).unwrap()).collect();
    assert_eq!(names, ["Hips", "LeftLeg", "Spine", "Head"]);
    assert_eq!(read.nodes, vec![2, 4, 3, 5]);
    let parents: Vec<_> = (0..s.len()).map(|i| s.parent(i)).collect();
    assert_eq!(parents, [None, Some(0), Some(0), Some(2)]);
    // Skin joint k (Head, LeftLeg, Hips, Spine) -> skeleton joint.
    assert_eq!(read.skin_to_joint, vec![3, 1, 0, 2]);
    // Spine's offset and rest rotation are its node's own (its parent is a joint).
    assert!((s.offset(2) - DVec3::new(0.0, 0.3, 0.05)).length() < 1e-7);
    assert!(read.rest_pose.rotations[2].angle_between(DQuat::from_rotation_x(-0.4)) < 1e-7);
    // Forward kinematics of the rest pose puts every joint where the scene's node
    // matrices do, and turns it the same way (f32 storage: 1e-6).
    let w = world(&nodes);
    let mut global = GlobalPose::new();
    s.forward_kinematics(&read.rest_pose, &mut global).unwrap();
    for (j, &n) in read.nodes.iter().enumerate() {
        let (_, rot, pos) = w[n].to_scale_rotation_translation();
        assert!(
            (global.positions[j] - pos).length() < 1e-6,
            "{}: {} vs {pos}",
            names[j],
            global.positions[j]
        );
        assert!(
            global.rotations[j].angle_between(rot) < 1e-6,
            "{}",
            names[j]
        );
    }
}

#[test]
fn errors_name_the_node() {
    let mut nodes = scene();
    nodes[3].s = [1.0, 2.0, 1.0];
    let e = read_gltf_skin(document(&nodes, &SKIN_JOINTS).as_bytes(), 0).unwrap_err();
    assert!(
        matches!(&e, GltfError::Scaled { node, .. } if node == "node 3 `Spine`"),
        "{e}"
    );
    assert!(e.to_string().contains("`Spine`"));

    // A scaled node between joints is refused too, by its own name.
    let mut nodes = scene();
    nodes[1].s = [0.5, 0.5, 0.5];
    let e = read_gltf_skin(document(&nodes, &SKIN_JOINTS).as_bytes(), 0).unwrap_err();
    assert!(e.to_string().contains("`Offset`"), "{e}");

    let mut nodes = scene();
    nodes[4].r = [0.0, 0.0, 0.0, 0.0];
    let e = read_gltf_skin(document(&nodes, &SKIN_JOINTS).as_bytes(), 0).unwrap_err();
    assert!(e.to_string().contains("`LeftLeg`"), "{e}");

    let e = read_gltf_skin(document(&scene(), &[5, 4, 2, 4]).as_bytes(), 0).unwrap_err();
    assert_eq!(
        e,
        GltfError::DuplicateJoint {
            node: "node 4 `LeftLeg`".into()
        }
    );

    let e = read_gltf_skin(document(&scene(), &SKIN_JOINTS).as_bytes(), 1).unwrap_err();
    assert_eq!(e, GltfError::NoSuchSkin { index: 1, skins: 1 });

    // Node 3 as the child of both 2 and 0.
    let mut nodes = scene();
    nodes[0].children.push(3);
    let e = read_gltf_skin(document(&nodes, &SKIN_JOINTS).as_bytes(), 0).unwrap_err();
    assert!(e.to_string().contains("`Spine`"), "{e}");

    assert!(matches!(
        read_gltf_skin(b"{ not json", 0),
        Err(GltfError::Document(_))
    ));
    // A joint index out of range is caught by the gltf crate's validation.
    assert!(read_gltf_skin(document(&scene(), &[5, 4, 9]).as_bytes(), 0).is_err());
}

#[test]
fn binary_glb_reads_the_same_skeleton() {
    // A GLB container: 12-byte header, then the JSON chunk padded with spaces to a
    // multiple of four bytes (the buffer stays a data URI, so no BIN chunk is needed).
    let text = document(&scene(), &SKIN_JOINTS);
    let mut json = text.into_bytes();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut glb = Vec::new();
    glb.extend_from_slice(b"glTF");
    glb.extend_from_slice(&2u32.to_le_bytes());
    glb.extend_from_slice(&((12 + 8 + json.len()) as u32).to_le_bytes());
    glb.extend_from_slice(&(json.len() as u32).to_le_bytes());
    glb.extend_from_slice(b"JSON");
    glb.extend_from_slice(&json);
    let from_glb = read_gltf_skin(&glb, 0).unwrap();
    let from_json = read_gltf_skin(document(&scene(), &SKIN_JOINTS).as_bytes(), 0).unwrap();
    assert_eq!(from_glb, from_json);
    // A truncated container is an error, not a panic.
    for cut in [4, 12, 20, glb.len() - 3] {
        assert!(read_gltf_skin(&glb[..cut], 0).is_err(), "cut at {cut}");
    }
}
