mod shadows_scenes;
use photostereo::shadows::*;
use shadows_scenes::*;

fn show(f: &Field, l: [f64; 3]) {
    let truth = cast_shadows_ray_march(&f.depth, &f.mask, f.width, f.height, l, 0.05).unwrap();
    let p = ShadowParams { cast_tolerance_px: 0.0, ..Default::default() };
    let s = cast_shadows_lines(&f.depth, &f.mask, f.width, f.height, l, &p).unwrap();
    println!("{} {:?} agreement {:?}", f.name, l, agreement(&s, &truth, &f.mask));
    for r in 0..f.height {
        let line: String = (0..f.width).map(|c| { let i = r * f.width + c;
            if !f.mask[i] { ' ' } else { match (s[i], truth[i]) { (false,false)=>'.', (true,true)=>'#', (true,false)=>'+', (false,true)=>'-' } } }).collect();
        println!("{line}");
    }
}
#[test]
fn explore2() {
    show(&bumps_with_holes(96, 3), [0.5389855446957563, 0.7697511313200571, 0.3420201433256688]);
    show(&block(96, 12.0), [0.5389855446957563, 0.7697511313200571, 0.3420201433256688]);
}
