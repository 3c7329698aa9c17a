//! The seed paper's ablation (`umbra bench ablation`, `bench::ablation`): at equal
//! samples, laser sampling and hidden-geometry sampling each lower the error of the
//! time-resolved radiance at a scan point, laser sampling by far the most (paths that
//! must find a 5 cm spot by BSDF sampling rarely do), and both together the most; the
//! outputs are written.

#[test]
fn each_technique_lowers_the_error_at_equal_samples() {
    let scene = umbra::bench::ablation::ablation_scene().unwrap();
    let a = umbra::bench::ablation::run(&scene, 8192, 32).unwrap();
    let err: Vec<f64> = a.variants.iter().map(|v| v.error).collect();
    for v in &a.variants {
        println!("{}: {:.2} %", v.label, 100.0 * v.error);
    }
    let (bsdf, laser, hidden, both) = (err[0], err[1], err[2], err[3]);
    assert!(
        laser < 0.2 * bsdf,
        "laser sampling {laser} vs BSDF only {bsdf}"
    );
    assert!(
        hidden < bsdf,
        "hidden-geometry sampling {hidden} vs BSDF only {bsdf}"
    );
    assert!(
        both < laser && both < hidden,
        "both {both} vs {laser} / {hidden}"
    );
    assert!(a.reference.iter().any(|&v| v > 0.0));
    let dir = std::env::temp_dir().join(format!("umbra-ablation-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    a.write_png(&dir.join("ablation.png")).unwrap();
    let csv = a.csv();
    assert_eq!(csv.lines().count(), 1 + scene.film.temporal_bins as usize);
    assert!(csv.starts_with("opl_m,reference,BSDF sampling only"));
    assert!(dir.join("ablation.png").metadata().unwrap().len() > 1000);
    let _ = std::fs::remove_dir_all(&dir);
}
