//! Bad input is an `Err` naming the field; scene descriptions build the right curves.

use sinew_curves::{
    ArcLengthTable, ArcParam, Curve, CurveError, CurveSpec, Ends, Epicycloid, FnCurve, ParamCurve,
    Plane, PlaneAxes, Polyline, Rose, Sampling, resample_by_spacing, resample_evenly,
    sample_uniform,
};
use sinew_math::DVec3;

fn field<T: std::fmt::Debug>(r: Result<T, CurveError>) -> String {
    match r {
        Err(CurveError::Invalid { field, reason }) => {
            assert!(!reason.is_empty());
            field
        }
        other => panic!("expected Invalid, got {other:?}"),
    }
}

#[test]
fn bad_curves_name_the_field() {
    let lab = Plane::lab();
    assert_eq!(field(Epicycloid::with_petals(0, 0.1, lab)), "petals");
    assert_eq!(field(Epicycloid::with_petals(5, 0.0, lab)), "r");
    assert_eq!(field(Epicycloid::with_petals(5, -1.0, lab)), "r");
    assert_eq!(field(Epicycloid::with_petals(5, f64::NAN, lab)), "r");
    assert_eq!(field(Epicycloid::with_petals(5, f64::INFINITY, lab)), "r");
    assert_eq!(field(Rose::from_frequency(0, 1.0, lab)), "k");
    assert_eq!(field(Rose::from_frequency(3, f64::NAN, lab)), "a");
    // A rose has an odd number of petals or a multiple of four.
    for petals in [0, 2, 6, 10] {
        assert_eq!(field(Rose::with_petals(petals, 1.0, lab)), "petals");
    }
    for petals in [1, 3, 4, 5, 8, 12] {
        let rose = Rose::with_petals(petals, 1.0, lab).unwrap();
        assert_eq!(rose.petal_count(), petals);
        let epi = Epicycloid::with_petals(petals, 0.1, lab).unwrap();
        assert_eq!(epi.petals(), petals);
    }
    assert_eq!(field(Polyline::new(vec![DVec3::X], Ends::Open)), "points");
    assert_eq!(field(Polyline::new(vec![], Ends::Closed)), "points");
    assert_eq!(
        field(Polyline::new(vec![DVec3::X, DVec3::NAN], Ends::Open)),
        "points[1]"
    );
    assert_eq!(
        field(Plane::new(DVec3::new(0.0, f64::NAN, 0.0), PlaneAxes::XZ)),
        "center.y"
    );
    let skew = PlaneAxes::Axes {
        u: DVec3::X,
        v: DVec3::new(0.1, 1.0, 0.0).normalize(),
    };
    assert_eq!(field(Plane::new(DVec3::ZERO, skew)), "plane.v");
    let long = PlaneAxes::Axes {
        u: DVec3::X * 2.0,
        v: DVec3::Y,
    };
    assert_eq!(field(Plane::new(DVec3::ZERO, long)), "plane.u");
    assert_eq!(
        field(FnCurve::new(1.0, 1.0, Ends::Open, |t| DVec3::X * t)),
        "t1"
    );
    assert_eq!(
        field(FnCurve::new(f64::NAN, 1.0, Ends::Open, |t| DVec3::X * t)),
        "t0"
    );
    assert_eq!(
        field(FnCurve::new(0.0, 1.0, Ends::Open, |t| DVec3::X / t)),
        "position"
    );
    let c = FnCurve::new(0.0, 1.0, Ends::Open, |t| DVec3::X * t).unwrap();
    assert_eq!(field(c.clone().with_breaks(vec![0.5, 0.4])), "breaks[1]");
    assert_eq!(field(c.clone().with_breaks(vec![1.0])), "breaks[0]");
    assert_eq!(field(c.with_step(0.0)), "step");
    // Nearly orthonormal axes are accepted and made exactly orthonormal.
    let near = PlaneAxes::Axes {
        u: DVec3::new(1.0, 1e-9, 0.0),
        v: DVec3::Z,
    };
    let (u, v) = Plane::new(DVec3::ZERO, near).unwrap().axes();
    assert!((u.length() - 1.0).abs() < 1e-15 && u.dot(v).abs() < 1e-16);
}

#[test]
fn bad_tolerances_and_counts_name_the_field() {
    let f = Epicycloid::lab_flower();
    for tol in [0.0, -1e-9, f64::NAN, f64::INFINITY] {
        assert_eq!(field(ArcLengthTable::new(&f, tol)), "tolerance");
    }
    let table = ArcLengthTable::new(&f, 1e-9).unwrap();
    assert_eq!(field(resample_evenly(&f, &table, 0)), "n");
    assert_eq!(field(sample_uniform(&f, 0)), "n");
    let open = Polyline::new(vec![DVec3::ZERO, DVec3::X], Ends::Open).unwrap();
    assert_eq!(field(resample_evenly(&open, &open, 1)), "n");
    for h in [0.0, -0.1, f64::NAN] {
        assert_eq!(field(resample_by_spacing(&f, &table, h)), "spacing");
    }
    assert_eq!(field(resample_by_spacing(&f, &table, 1e-300)), "spacing");
    // A bad break point reported by a curve.
    let c = FnCurve::new(0.0, 1.0, Ends::Open, |t| DVec3::X * t).unwrap();
    assert!(ArcLengthTable::new(&c, 1e-9).is_ok());
}

#[test]
fn a_kink_inside_a_panel_is_refused_not_silently_wrong() {
    // |t - 0.3| speed with the kink not declared: the error bound cannot converge where
    // the speed is not smooth, so the table refuses (or, if it accepts, it is within).
    let c = FnCurve::with_derivative(
        0.0,
        1.0,
        Ends::Open,
        |t| DVec3::X * (0.5 * (t - 0.3) * (t - 0.3).abs()),
        |t| DVec3::X * (t - 0.3).abs(),
    )
    .unwrap();
    let exact = 0.5 * (0.3 * 0.3 + 0.7 * 0.7);
    for tol in [1e-4, 1e-8, 1e-12] {
        match ArcLengthTable::new(&c, tol) {
            Ok(t) => assert!((t.length() - exact).abs() <= tol, "tol {tol:e}"),
            Err(CurveError::ToleranceNotReached { .. }) => {}
            Err(e) => panic!("{e}"),
        }
    }
    // Declared, it is exact.
    let c = c.with_breaks(vec![0.3]).unwrap();
    let t = ArcLengthTable::new(&c, 1e-12).unwrap();
    assert!((t.length() - exact).abs() <= 1e-12);
}

#[test]
fn specs_build_the_curves() {
    let flower = CurveSpec::lab_flower().build().unwrap();
    assert_eq!(flower, Curve::Epicycloid(Epicycloid::lab_flower()));
    assert_eq!(flower.exact_length(), Some(48.0 * 0.1));
    let bad = CurveSpec::Epicycloid {
        petals: 5,
        r: -0.1,
        center: DVec3::ZERO,
        plane: PlaneAxes::XZ,
    };
    assert_eq!(field(bad.build()), "r");
    let rose = CurveSpec::Rose {
        k: 4,
        a: 0.5,
        center: DVec3::new(1.0, 2.0, 3.0),
        plane: PlaneAxes::XY,
    }
    .build()
    .unwrap();
    assert_eq!(rose.position(0.0), DVec3::new(1.5, 2.0, 3.0));
    let poly = CurveSpec::Polyline {
        points: vec![DVec3::ZERO, DVec3::new(0.0, 3.0, 4.0)],
        closed: false,
    };
    assert_eq!(poly.build().unwrap().exact_length(), Some(5.0));
    assert_eq!(
        field(
            CurveSpec::Polyline {
                points: vec![],
                closed: true
            }
            .build()
        ),
        "points"
    );
}

#[test]
fn samplings_run_from_specs() {
    let flower = CurveSpec::lab_flower().build().unwrap();
    let s = flower
        .sample(&Sampling::ArcLength {
            n: 500,
            tolerance: 1e-12,
        })
        .unwrap();
    assert_eq!(s.points.len(), 500);
    assert!(s.arc.unwrap().rel_dev_max < 1e-11);
    assert!((s.length.unwrap() - 4.8).abs() < 1e-12);
    let u = flower.sample(&Sampling::Uniform { n: 500 }).unwrap();
    assert_eq!(u.points.len(), 500);
    assert!(u.arc.is_none());
    let sp = flower
        .sample(&Sampling::ArcSpacing {
            spacing: 0.01,
            tolerance: 1e-9,
        })
        .unwrap();
    assert_eq!(sp.points.len(), 480);
    assert_eq!(
        field(flower.sample(&Sampling::ArcLength {
            n: 10,
            tolerance: 0.0
        })),
        "tolerance"
    );
    let poly = CurveSpec::Polyline {
        points: vec![DVec3::ZERO, DVec3::X * 2.0],
        closed: false,
    }
    .build()
    .unwrap();
    let s = poly
        .sample(&Sampling::ArcLength {
            n: 3,
            tolerance: 1.0,
        })
        .unwrap();
    assert_eq!(s.points[1], DVec3::X);
}

#[cfg(feature = "serde")]
#[test]
fn specs_are_serializable() {
    fn both<T: serde::Serialize + for<'de> serde::Deserialize<'de>>() {}
    both::<CurveSpec>();
    both::<Sampling>();
    both::<PlaneAxes>();
    both::<sinew_curves::SpacingStats>();
}
