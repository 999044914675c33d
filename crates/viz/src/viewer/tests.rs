//! Tests of the page's data: validation messages, the embedded encoding read back, and
//! decimation to the budget.

use super::encode::group_thousands;
use super::page::{largest_strain, triangle_rest_lengths};
use super::*;
use serde_json::Value;

/// A cloth-like page: an `n x n` grid of particles waving over `frames` frames, with
/// structural springs, two triangles per cell, a sphere and a ground plane.
fn grid_page(n: usize, frames: usize) -> ViewerPage {
    let mut page = ViewerPage::new("grid", PageKind::Cloth);
    let id = |i: usize, j: usize| i * n + j;
    for i in 0..n {
        for j in 0..n {
            if j + 1 < n {
                page.segments.push((id(i, j), id(i, j + 1)));
            }
            if i + 1 < n {
                page.segments.push((id(i, j), id(i + 1, j)));
            }
            if i + 1 < n && j + 1 < n {
                page.triangles
                    .push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                page.triangles
                    .push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            }
        }
    }
    page.rest_lengths = vec![0.1; page.segments.len()];
    page.fixed = vec![0, n - 1];
    let mut energy = Vec::new();
    for k in 0..frames {
        let t = k as f64 / 30.0;
        let points = (0..n * n)
            .map(|p| {
                let (i, j) = ((p / n) as f64, (p % n) as f64);
                DVec3::new(0.1 * j, 1.0 - 0.02 * t * i, 0.1 * i + 0.01 * (t + j).sin())
            })
            .collect();
        page.frames.push(Frame {
            time: t,
            points,
            goals: Vec::new(),
            colliders: vec![
                Collider::HalfSpace {
                    point: DVec3::ZERO,
                    normal: DVec3::Y,
                },
                Collider::Sphere {
                    center: DVec3::new(0.5, 0.3, 0.5),
                    radius: 0.25,
                },
            ],
        });
        energy.push(1.0 / (1.0 + t));
    }
    page.charts.push(Series::new("total energy", "J", energy));
    page.metrics.push(("steps".to_owned(), frames.to_string()));
    page
}

/// A chain page: three joints, one goal per frame, an error chart.
fn chain_page(frames: usize) -> ViewerPage {
    let mut page = ViewerPage::new("chain <&> \"quoted\"", PageKind::IkTrack);
    page.segments = vec![(0, 1), (1, 2)];
    page.effectors = vec![2];
    page.fixed = vec![0];
    let mut error = Vec::new();
    for k in 0..frames {
        let a = 0.1 * k as f64;
        page.frames.push(Frame {
            time: k as f64 / 60.0,
            points: vec![
                DVec3::ZERO,
                DVec3::new(a.cos(), a.sin(), 0.0),
                DVec3::new(2.0 * a.cos(), 2.0 * a.sin(), 0.0),
            ],
            goals: vec![DVec3::new(2.0 * a.cos(), 2.0 * a.sin(), 0.1)],
            colliders: Vec::new(),
        });
        error.push(0.1);
        page.target_path
            .push(DVec3::new(2.0 * a.cos(), 2.0 * a.sin(), 0.1));
    }
    page.charts.push(Series::new("effector error", "m", error));
    page.metrics
        .push(("max error".to_owned(), "0.1 m <b>".to_owned()));
    page
}

/// The JSON object embedded in a page.
fn embedded_data(html: &str) -> Value {
    let open = "<script type=\"application/json\" id=\"sinew-data\">";
    let start = html.find(open).expect("data element") + open.len();
    let end = start + html[start..].find("</script>").expect("end of data");
    serde_json::from_str(&html[start..end]).expect("the data is JSON")
}

/// The f32 values of a base64 field of the embedded data.
fn decode_f32(field: &Value) -> Vec<f32> {
    let text = field.as_str().expect("a base64 string");
    let bytes = encode::tests::decode_base64(text);
    bytes
        .chunks(4)
        .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
        .collect()
}

#[test]
fn positions_goals_and_charts_read_back_as_the_f32_of_the_input() {
    let page = chain_page(40);
    let rendered = render_page(&page, &Budget::default()).unwrap();
    assert_eq!(rendered.shown_frames, 40);
    let data = embedded_data(&rendered.html);
    let points = decode_f32(&data["points"]);
    let goals = decode_f32(&data["goals"]);
    assert_eq!(points.len(), 40 * 3 * 3);
    for (k, frame) in page.frames.iter().enumerate() {
        for (i, p) in frame.points.iter().enumerate() {
            for (c, v) in [p.x, p.y, p.z].into_iter().enumerate() {
                assert_eq!(points[(k * 3 + i) * 3 + c], v as f32, "frame {k} point {i}");
            }
        }
        assert_eq!(goals[3 * k], frame.goals[0].x as f32, "frame {k} goal");
    }
    let times = decode_f32(&data["times"]);
    assert_eq!(times[39], (39.0 / 60.0) as f32);
    assert_eq!(data["pointCount"], 3);
    assert_eq!(data["goalCount"], 1);
    assert_eq!(data["segments"], serde_json::json!([0, 1, 1, 2]));
    assert_eq!(data["kind"], "ik");
    assert_eq!(data["title"], page.title.as_str());
    assert_eq!(decode_f32(&data["charts"][0]["values"]).len(), 40);
    assert_eq!(data["chartFrames"], Value::Null);
    assert_eq!(decode_f32(&data["targetPath"]).len(), 40 * 3);
}

#[test]
fn text_is_escaped_in_the_markup() {
    let html = render_page(&chain_page(3), &Budget::default())
        .unwrap()
        .html;
    assert!(html.contains("<h1>chain &lt;&amp;&gt; &quot;quoted&quot;</h1>"));
    assert!(html.contains("<td>0.1 m &lt;b&gt;</td>"));
    // The only script-closing tags are the two that end the data and the script.
    assert_eq!(html.matches("</script>").count(), 2);
    assert!(
        !html.contains("http://") && !html.contains("https://"),
        "no URL fetched"
    );
}

#[test]
fn colliders_are_written_once_when_static_and_per_frame_when_moving() {
    let page = grid_page(4, 10);
    let data = embedded_data(&render_page(&page, &Budget::default()).unwrap().html);
    let colliders = data["colliders"].as_array().unwrap();
    assert_eq!(colliders.len(), 1);
    assert_eq!(colliders[0][1]["k"], "sphere");
    assert_eq!(colliders[0][1]["r"].as_f64().unwrap() as f32, 0.25);
    assert_eq!(colliders[0][0]["n"], serde_json::json!([0.0, 1.0, 0.0]));

    let mut moving = page.clone();
    for (k, frame) in moving.frames.iter_mut().enumerate() {
        frame.colliders.push(Collider::Capsule {
            a: DVec3::new(k as f64, 0.0, 0.0),
            b: DVec3::new(k as f64, 1.0, 0.0),
            radius: 0.1,
        });
    }
    let data = embedded_data(&render_page(&moving, &Budget::default()).unwrap().html);
    let colliders = data["colliders"].as_array().unwrap();
    assert_eq!(colliders.len(), 10);
    assert_eq!(colliders[7][2]["k"], "capsule");
    assert_eq!(colliders[7][2]["a"][0], 7.0);
}

#[test]
fn triangle_rest_lengths_come_from_springs_or_the_first_frame() {
    let mut page = grid_page(3, 2);
    // Only structural springs: the diagonal of each triangle has no spring, so its rest
    // length is its length in the first frame.
    let rest = triangle_rest_lengths(&page);
    assert_eq!(rest.len(), 3 * page.triangles.len());
    let first = &page.frames[0].points;
    for (tri, r) in page.triangles.iter().zip(rest.chunks(3)) {
        for e in 0..3 {
            let (i, j) = (tri[e], tri[(e + 1) % 3]);
            let spring = page
                .segments
                .iter()
                .any(|&(a, b)| (a, b) == (i, j) || (a, b) == (j, i));
            let expected = if spring {
                0.1
            } else {
                first[i].distance(first[j])
            };
            assert_eq!(r[e], expected, "triangle {tri:?} edge {e}");
        }
    }
    // The strain scale defaults to the largest strain over the shown frames.
    page.rest_lengths = vec![0.05; page.segments.len()];
    let rest = triangle_rest_lengths(&page);
    let scale = largest_strain(&page, &[0, 1], &rest).unwrap();
    let mut expected: f64 = 0.0;
    for frame in &page.frames {
        for &(i, j) in &page.segments {
            expected = expected.max((frame.points[i].distance(frame.points[j]) / 0.05 - 1.0).abs());
        }
    }
    assert!(scale >= expected && scale.is_finite());
}

#[test]
fn all_frames_are_shown_when_they_fit() {
    let rendered = render_page(&grid_page(5, 30), &Budget::default()).unwrap();
    assert_eq!(rendered.shown_frames, 30);
    assert_eq!(rendered.frame_indices, (0..30).collect::<Vec<_>>());
    assert!(rendered.html.contains("showing all 30 frames"));
}

#[test]
fn decimation_fits_the_byte_budget_keeps_first_and_last_and_chooses_evenly() {
    // 21 x 21 particles: about 7 kB of base64 a frame, so 600 frames are about 4 MB.
    let page = grid_page(21, 600);
    for max_bytes in [300_000, 1_000_000, 2_500_000] {
        let budget = Budget {
            max_bytes,
            max_frames: 10_000,
        };
        let rendered = render_page(&page, &budget).unwrap();
        let len = rendered.html.len();
        assert!(len <= max_bytes, "{len} bytes over {max_bytes}");
        assert!(rendered.shown_frames < 600, "{max_bytes}: nothing dropped");
        assert_eq!(
            rendered.frame_indices,
            pick_even(600, rendered.shown_frames),
            "{max_bytes}: an even choice"
        );
        assert_eq!(rendered.frame_indices[0], 0);
        assert_eq!(*rendered.frame_indices.last().unwrap(), 599);
        // The budget is used, not wasted: one more frame would not have fit.
        let per_frame = 21 * 21 * 3 * 4 * 4 / 3 + 8;
        assert!(
            len + 2 * per_frame > max_bytes,
            "{max_bytes}: {len} bytes leaves room for more frames"
        );
        let note = format!(
            "showing {} of 600 frames",
            group_thousands(rendered.shown_frames)
        );
        assert!(rendered.html.contains(&note), "{note}");
        // Deterministic: the same input gives the same bytes.
        assert_eq!(render_page(&page, &budget).unwrap().html, rendered.html);
        // The data holds exactly the chosen frames.
        let data = embedded_data(&rendered.html);
        let frames: Vec<usize> = data["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap() as usize)
            .collect();
        assert_eq!(frames, rendered.frame_indices);
        let points = decode_f32(&data["points"]);
        assert_eq!(points.len(), rendered.shown_frames * 21 * 21 * 3);
        let last = &page.frames[599].points[440];
        assert_eq!(points[points.len() - 1], last.z as f32);
        // Charts keep every frame of the run.
        assert_eq!(decode_f32(&data["charts"][0]["values"]).len(), 600);
    }
}

#[test]
fn the_frame_budget_caps_small_frames() {
    let budget = Budget {
        max_bytes: 5_000_000,
        max_frames: 10,
    };
    let rendered = render_page(&chain_page(95), &budget).unwrap();
    assert_eq!(rendered.frame_indices, pick_even(95, 10));
    assert!(rendered.html.contains("showing 10 of 95 frames"));
}

#[test]
fn long_charts_are_thinned_evenly() {
    let page = chain_page(MAX_CHART_POINTS + 1234);
    let rendered = render_page(&page, &Budget::default()).unwrap();
    let data = embedded_data(&rendered.html);
    let chart_frames: Vec<usize> = data["chartFrames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as usize)
        .collect();
    assert_eq!(chart_frames, pick_even(page.frames.len(), MAX_CHART_POINTS));
    assert_eq!(
        decode_f32(&data["charts"][0]["values"]).len(),
        MAX_CHART_POINTS
    );
}

#[test]
fn a_budget_too_small_for_two_frames_is_an_error() {
    let budget = Budget {
        max_bytes: 20_000,
        max_frames: 1000,
    };
    let err = render_page(&grid_page(21, 50), &budget).unwrap_err();
    match &err {
        ViewerError::OverBudget {
            bytes, max_bytes, ..
        } => {
            assert!(*bytes > 20_000);
            assert_eq!(*max_bytes, 20_000);
        }
        other => panic!("expected OverBudget, got {other:?}"),
    }
    assert!(err.to_string().contains("'grid'"), "{err}");
}

/// Checks that `change` makes the chain page invalid with a message containing
/// `expected`.
fn check_invalid(change: impl FnOnce(&mut ViewerPage), expected: &str) {
    let mut page = chain_page(5);
    change(&mut page);
    let err = page.validate().unwrap_err();
    assert!(
        matches!(err, ViewerError::InvalidPage { .. }),
        "{expected}: {err:?}"
    );
    let text = err.to_string();
    assert!(text.contains(expected), "expected {expected:?} in {text:?}");
    assert_eq!(render_page(&page, &Budget::default()).unwrap_err(), err);
}

#[test]
fn bad_input_is_an_error_naming_the_item() {
    check_invalid(|p| p.frames.clear(), "no frames");
    check_invalid(
        |p| p.frames[3].points.pop().map(|_| ()).unwrap(),
        "frame 3 has 2 points",
    );
    check_invalid(|p| p.frames[2].goals.clear(), "frame 2 has 0 goals");
    check_invalid(|p| p.frames[4].points[1].y = f64::NAN, "frame 4, point 1");
    check_invalid(
        |p| p.frames[1].goals[0].x = f64::INFINITY,
        "frame 1, goal 0",
    );
    check_invalid(|p| p.frames[1].points[2].x = 1e300, "frame 1, point 2");
    check_invalid(|p| p.frames[0].time = f64::NAN, "frame 0: time");
    check_invalid(
        |p| {
            p.frames[2].colliders.push(Collider::Sphere {
                center: DVec3::ZERO,
                radius: -1.0,
            })
        },
        "frame 2, collider 0 (sphere): radius -1",
    );
    check_invalid(
        |p| {
            p.frames[0].colliders.push(Collider::HalfSpace {
                point: DVec3::ZERO,
                normal: DVec3::ZERO,
            })
        },
        "collider 0 (half-space): normal",
    );
    check_invalid(
        |p| {
            p.frames[0].colliders.push(Collider::Capsule {
                a: DVec3::ZERO,
                b: DVec3::NAN,
                radius: 1.0,
            })
        },
        "collider 0 (capsule): end b",
    );
    check_invalid(
        |p| p.segments.push((1, 9)),
        "segment 2 (1, 9): point 9 out of range",
    );
    check_invalid(
        |p| p.rest_lengths = vec![1.0],
        "1 rest lengths for 2 segments",
    );
    check_invalid(
        |p| p.rest_lengths = vec![1.0, 0.0],
        "segment 1: rest length 0",
    );
    check_invalid(
        |p| p.triangles.push([0, 1, 3]),
        "triangle 0 [0, 1, 3]: point 3",
    );
    check_invalid(|p| p.fixed.push(7), "fixed point 7 out of range");
    check_invalid(|p| p.effectors.push(3), "effector 3 out of range");
    check_invalid(|p| p.target_path[2].z = f64::NAN, "target path point 2");
    check_invalid(
        |p| p.charts[0].values.pop().map(|_| ()).unwrap(),
        "chart 'effector error': 4 values for 5 frames",
    );
    check_invalid(
        |p| p.charts[0].values[3] = f64::NAN,
        "chart 'effector error', frame 3",
    );
    check_invalid(|p| p.strain_scale = Some(0.0), "strain scale 0");
}

#[test]
fn pages_and_the_index_are_written_to_disk() {
    let dir = std::env::temp_dir().join(format!("sinew-viz-unit-{}", std::process::id()));
    let summary = write_page(&dir, "chain.html", &chain_page(12), &Budget::default()).unwrap();
    let written = std::fs::read_to_string(dir.join("chain.html")).unwrap();
    assert_eq!(summary.bytes, written.len());
    assert_eq!((summary.shown_frames, summary.total_frames), (12, 12));
    assert_eq!(
        summary.headline,
        vec![("max error".to_owned(), "0.1 m <b>".to_owned())]
    );
    let mut second = summary.clone();
    second.file_name = "cloth.html".to_owned();
    second.kind = PageKind::Cloth;
    second.shown_frames = 300;
    second.total_frames = 2400;
    let index = write_scene_index(&dir, "lab <4>", &[summary, second]).unwrap();
    let html = std::fs::read_to_string(&index).unwrap();
    assert!(html.contains("<h1>Scene lab &lt;4&gt;</h1>"));
    assert!(html.contains("<a href=\"chain.html\">"));
    assert!(html.contains("<a href=\"cloth.html\">"));
    assert!(html.contains("300 of 2 400"));
    assert!(html.contains("max error: 0.1 m &lt;b&gt;"));
    assert!(html.contains("2 interactive pages"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_unwritable_path_is_an_io_error_naming_it() {
    let file = std::env::temp_dir().join(format!("sinew-viz-file-{}", std::process::id()));
    std::fs::write(&file, "not a directory").unwrap();
    let err = write_page(&file, "page.html", &chain_page(2), &Budget::default()).unwrap_err();
    assert!(matches!(err, ViewerError::Io { .. }), "{err:?}");
    assert!(err.to_string().contains("page.html"), "{err}");
    std::fs::remove_file(&file).unwrap();
}

#[test]
fn file_names_must_be_plain_and_links_are_percent_encoded() {
    let dir = std::env::temp_dir().join(format!("sinew-viz-names-{}", std::process::id()));
    for bad in [
        "",
        ".",
        "..",
        "../escape.html",
        "sub/page.html",
        "a\\b.html",
    ] {
        let err = write_page(&dir, bad, &chain_page(2), &Budget::default()).unwrap_err();
        assert!(
            err.to_string().contains(&format!("file name {bad:?}")),
            "{bad:?}: {err}"
        );
    }
    assert!(!dir.exists(), "nothing written for a bad name");
    let summary = write_page(&dir, "a b#1.html", &chain_page(2), &Budget::default()).unwrap();
    assert!(dir.join("a b#1.html").is_file());
    let html = index_html("s", &[summary]);
    assert!(html.contains("<a href=\"a%20b%231.html\">"), "{html}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_zero_frame_budget_is_an_error_naming_the_budget() {
    let budget = Budget {
        max_bytes: 5_000_000,
        max_frames: 0,
    };
    let err = render_page(&chain_page(3), &budget).unwrap_err();
    assert!(err.to_string().contains("budget: max_frames is 0"), "{err}");
}
