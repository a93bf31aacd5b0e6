//! The occupancy grid carved by the masks of a dataset loaded from disk (the Blender images'
//! alpha): the visual hull keeps every opaque training pixel's ray.
#![allow(clippy::unwrap_used, missing_docs)]

use mipnerf_core::dataset::Split;
use mipnerf_core::occupancy::{CARVED, OccupancyConfig, OccupancyGrid, auto_bound};
use mipnerf_data::LoadOptions;

#[test]
fn the_visual_hull_of_the_masks_keeps_every_opaque_training_pixel() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/lego_tiny");
    let ds = mipnerf_data::load(&dir, Split::Train, &LoadOptions::default()).unwrap();
    let bound = auto_bound(&ds).unwrap();
    let mut grid = OccupancyGrid::new(OccupancyConfig { resolution: 48, bound, ..OccupancyConfig::default() }).unwrap();
    let carved = grid.carve_with_masks(&ds);
    let cells = 48usize.pow(3);
    assert!(carved * 2 > cells, "only {carved} of {cells} cells carved");
    assert_eq!(grid.opacity.iter().filter(|&&v| v == CARVED).count(), carved);
    let mut spans = Vec::new();
    let mut lost = Vec::new();
    let mut opaque = 0;
    for (v, view) in ds.views().iter().enumerate() {
        for y in 0..view.camera.height {
            for x in 0..view.camera.width {
                let i = (y * view.camera.width + x) as usize;
                if view.pixels.rgba(i)[3] < 0.5 / 255.0 {
                    continue;
                }
                opaque += 1;
                let r = ds.ray(v, x, y);
                spans.clear();
                grid.ray_segments(&r, &mut spans);
                if spans.is_empty() {
                    lost.push(format!("view {v} pixel ({x}, {y})"));
                }
            }
        }
    }
    assert!(opaque > 1000, "{opaque} opaque pixels");
    assert!(
        lost.is_empty(),
        "{} of {opaque} opaque pixels see no occupied cell: {:?}",
        lost.len(),
        &lost[..lost.len().min(10)]
    );
}
