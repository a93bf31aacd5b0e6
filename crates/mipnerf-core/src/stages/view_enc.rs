//! The positional encoding of the view directions. Kernel: `view_enc.wgsl`.

use crate::cone::Ray;
use crate::mip;

/// The positional encoding of each ray's unit view direction (degrees `0..deg_view`, with the
/// identity: `3 + 6 deg_view` values per ray), the colour branch's input. Kernel:
/// `view_enc.wgsl`.
///
/// # Panics
/// If `out` is not `rays.len() * (3 + 6 deg_view)` long.
pub fn encode_view_directions(rays: &[Ray], deg_view: u32, out: &mut [f32]) {
    let width = mip::pos_enc_len(0, deg_view, true);
    assert_eq!(out.len(), rays.len() * width, "encode_view_directions: output");
    for (ray, dst) in rays.iter().zip(out.chunks_exact_mut(width)) {
        mip::pos_enc(ray.viewdir, 0, deg_view, true, dst);
    }
}
