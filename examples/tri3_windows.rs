//! How wide the box splat's windows are on the `tri3` speed case: per block of eight
//! sub-triangles and measurement, the bins its window spans (the union of its pulses'
//! bins, what `splat_window` walks) against its longest single pulse. Sampled over
//! every 37th scan point of the 64 x 64 scan.
use umbra::film::{Film, LANES};
use umbra::geometry::SceneGeometry;
use umbra::transport::tri3::Tri3Mesh;
use umbra::transport::tri3_kernel::{self, PulseBlock};
use umbra::transport::MeasurementCtx;

fn main() {
    let scene = umbra::bench::tri3_speed_scene().unwrap();
    let geom = SceneGeometry::build(&scene);
    let film = Film::new(&scene.film);
    let mesh = Tri3Mesh::build(&scene, &geom, 0.15);
    let (mut window, mut longest, mut blocks) = (0u64, 0u64, 0u64);
    let mut pulses = PulseBlock::default();
    for m in (0..scene.num_measurements()).step_by(37) {
        let ctx = MeasurementCtx::new(&scene, &geom, &film, m);
        let frame = tri3_kernel::frame(&ctx, &film);
        for (b, block) in mesh.blocks.iter().enumerate() {
            block.pulses::<true>(&frame, &mesh.block_frame(&frame, b), &mut pulses);
            let [t0, _, t2] = pulses.lanes.t();
            let first = (0..LANES)
                .map(|j| t0[j].floor())
                .fold(f32::INFINITY, f32::min);
            let last = (0..LANES)
                .map(|j| t2[j].floor())
                .fold(f32::NEG_INFINITY, f32::max);
            let span = (0..LANES).map(|j| (t2[j].floor() - t0[j].floor()) as u64 + 1);
            window += (last - first) as u64 + 1;
            longest += span.max().unwrap_or(0);
            blocks += 1;
        }
    }
    let b = blocks as f64;
    println!(
        "{blocks} block-measurements: mean window {:.2} bins, mean longest pulse {:.2} bins",
        window as f64 / b,
        longest as f64 / b
    );
}
