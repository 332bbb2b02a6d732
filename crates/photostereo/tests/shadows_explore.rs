mod shadows_scenes;
use photostereo::shadows::*;
use shadows_scenes::*;

#[test]
fn explore() {
    let tilts = [0.0, 10.0, 45.0, 55.0, 90.0, 100.0, 145.0, 190.0, 235.0, 280.0, 325.0];
    let slants = [20.0, 35.0, 50.0, 70.0];
    let ls = lights(&tilts, &slants);
    let fields = [block(96, 12.0), sphere_cap(96), bowl(96), bumps(96, 1), bumps(96, 7), bumps_with_holes(96, 3)];
    for f in &fields {
        let truth0: Vec<Vec<bool>> = ls.iter().map(|l| cast_shadows_ray_march(&f.depth, &f.mask, f.width, f.height, *l, 0.05, 0.0).unwrap()).collect();
        for tol in [0.0, 0.02, 0.05, 0.1, 0.25] {
            let p = ShadowParams { cast_tolerance_px: tol, ..Default::default() };
            let (mut min_agree, mut min_iou, mut fp, mut fneg, mut lit_fp) = (1.0f64, 1.0f64, 0usize, 0usize, 0usize);
            for (k, l) in ls.iter().enumerate() {
                let truth = cast_shadows_ray_march(&f.depth, &f.mask, f.width, f.height, *l, 0.05, tol).unwrap();
                let s = cast_shadows(&f.depth, &f.mask, f.width, f.height, *l, &p).unwrap();
                let (a, iou) = agreement(&s, &truth, &f.mask);
                min_agree = min_agree.min(a); min_iou = min_iou.min(iou);
                for i in 0..s.len() { if s[i] && !truth[i] { fp += 1 } if !s[i] && truth[i] { fneg += 1 } if s[i] && !truth0[k][i] { lit_fp += 1 } }
            }
            println!("{:18} tol {tol:.2}: min agree {:.4} min IoU {:.4} fp {fp} fn {fneg} | shadowed but lit at tol 0: {lit_fp}", f.name, min_agree, min_iou);
        }
    }
}
