use maobi_shared::{energy::energy, presets, Brush, BrushParams, Pose, Quat, Vec3};
fn main() {
    for ratio in [0.001f32, 0.02, 1.0] {
        let base = presets::LARGE;
        let params = BrushParams { axial_stiffness: base.axial_stiffness * 1000.0, tie_stiffness: base.tie_stiffness * 1000.0, substeps_per_tick: 1, compression_ratio: ratio, ..base };
        let p = Pose::new(Vec3::from_f64([0.0, 0.0, 60.0]), Quat::IDENTITY);
        let mut b = Brush::<f64>::new(params, p).unwrap();
        let mut out = String::new();
        for s in 0..400 { b.substep(p); if s % 40 == 0 { out += &format!(" {:.1e}", energy(&b).total()); } }
        println!("ratio {ratio}:{out}");
        let s = b.spine();
        println!("   z: {:?}", s.iter().map(|v| (v.z * 100.0).round() / 100.0).collect::<Vec<_>>());
    }
}
