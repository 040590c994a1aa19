//! Every WGSL file in shaders/ parses and validates with naga.

#[test]
fn every_wgsl_file_validates() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).expect("shaders/ exists") {
        let path = entry.expect("dir entry").path();
        if path.extension().is_some_and(|e| e == "wgsl") {
            let src = std::fs::read_to_string(&path).expect("readable");
            let module = naga::front::wgsl::parse_str(&src)
                .unwrap_or_else(|e| panic!("{}: {}", path.display(), e.emit_to_string(&src)));
            naga::valid::Validator::new(
                naga::valid::ValidationFlags::all(),
                naga::valid::Capabilities::all(),
            )
            .validate(&module)
            .unwrap_or_else(|e| panic!("{}: {e:?}", path.display()));
            count += 1;
        }
    }
    assert!(
        count >= 2,
        "expected the hemisphere and view shaders, found {count}"
    );
}

/// Cell directions must not come from the driver's f32 sin/cos (their
/// precision is unspecified and differs between drivers): the hemisphere
/// shader reads them from a table computed once in f64.
#[test]
fn hemisphere_cell_directions_come_from_the_f64_table() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders/hemisphere.wgsl");
    let src = std::fs::read_to_string(&path).expect("readable");
    let module = naga::front::wgsl::parse_str(&src).expect("parses");
    let functions = module
        .functions
        .iter()
        .map(|(_, f)| f)
        .chain(module.entry_points.iter().map(|e| &e.function));
    for f in functions {
        for (_, e) in f.expressions.iter() {
            if let naga::Expression::Math { fun, .. } = e {
                assert!(
                    !matches!(fun, naga::MathFunction::Sin | naga::MathFunction::Cos),
                    "{}: {fun:?} in {:?}",
                    path.display(),
                    f.name
                );
            }
        }
    }
    // The table itself: f64 values rounded once.
    let res = radiosity::hemisphere::Resolution {
        rows: 128,
        cols: 512,
    };
    let t = radiosity::hemisphere::direction_table(res);
    assert_eq!(t.len(), (res.rows + res.cols) as usize);
    let phi = 0.5 * std::f64::consts::FRAC_PI_2 / 128.0;
    assert_eq!(t[0], [phi.sin() as f32, phi.cos() as f32]);
    let theta = 511.5 * std::f64::consts::TAU / 512.0;
    assert_eq!(t[128 + 511], [theta.cos() as f32, theta.sin() as f32]);
}
