// Reading the Tri-Mip field's planes (mipnerf-core's `tri_mip.rs`): where a point and a footprint
// fall on the three planes (xy, xz, yz), and the 8 taps a plane reads there (bilinear at the two
// levels around the footprint's). Included by `tri_mip.wgsl` and `occupancy_probe.wgsl`, which
// bind the planes as `model_params` (level 0, the model's first parameters, laid out
// [plane][v][u][feature]) and `pyramid` (levels 1.., one after the other, each laid out as level 0).

// The planes' shape: texels along a side of level 0, features a texel, pyramid levels (level 0
// included).
struct Planes {
    resolution: u32,
    features: u32,
    levels: u32,
}

// Taps a plane reads: 2 levels x 4 bilinear corners.
const TAPS_PER_PLANE: u32 = 8u;

fn plane_side(planes: Planes, level: u32) -> u32 {
    return planes.resolution >> level;
}

// Where level `level` >= 1 starts in `pyramid`.
fn plane_level_base(planes: Planes, level: u32) -> u32 {
    var base = 0u;
    for (var k = 1u; k < level; k = k + 1u) {
        let s = plane_side(planes, k);
        base = base + 3u * s * s * planes.features;
    }
    return base;
}

// A point `x` with a footprint of `radius` (over the box's side) in the planes' box, the cube
// [-half_side, half_side]^3: the point in [0, 1]^3 and the level it reads (`Model::encode_samples`;
// level 0 for point samples, `pre_filtered` 0).
fn plane_point(planes: Planes, half_side: f32, pre_filtered: bool, x: vec3<f32>, radius: f32) -> vec4<f32> {
    let at = (x + vec3<f32>(half_side)) / (2.0 * half_side);
    var level = 0.0;
    if (pre_filtered) {
        // tri_mip::level_of (a point's log2(0) = -inf reads level 0; WGSL promises nothing of a
        // NaN radius, which only NaN rays give).
        level = clamp(log2(2.0 * radius * f32(planes.resolution)), 0.0, f32(planes.levels - 1u));
    }
    return vec4<f32>(at, level);
}

// The footprint's radius (over the box's side) of a density probe of `variance` on each axis:
// its isotropic standard deviation (`Model::encode_probe`), sqrt of the mean variance.
fn probe_footprint(variance: f32, half_side: f32) -> f32 {
    return 2.0 * sqrt(max(((variance + variance) + variance) / 3.0, 0.0)) / (2.0 * half_side);
}

// One tap: the texel's level, where its first feature is (in `model_params` for level 0, in
// `pyramid` above), its weight.
struct Tap {
    level: u32,
    offset: u32,
    weight: f32,
}

// The two texels around `t` along a side of `size` texels (clamped to the edge) and the
// weight of the second: tri_mip::taps' `corner`.
fn corner(t: f32, size: u32) -> vec3<f32> {
    let f = clamp(t, 0.0, 1.0) * f32(size) - 0.5;
    let i = floor(f);
    let i0 = min(u32(max(i, 0.0)), size - 1u);
    let i1 = min(u32(max(i + 1.0, 0.0)), size - 1u);
    return vec3<f32>(f32(i0), f32(i1), f - i);
}

// Tap `k` (0..8) of plane `plane` for a point `at` read at `level`: tri_mip::taps, in its order
// (the lower level's 4 corners, then the upper level's; corners (u0, v0), (u1, v0), (u0, v1),
// (u1, v1)).
fn plane_tap(planes: Planes, plane: u32, at: vec3<f32>, level_in: f32, k: u32) -> Tap {
    let top = planes.levels - 1u;
    let level = clamp(level_in, 0.0, f32(top));
    let l0 = min(u32(floor(level)), top);
    let l1 = min(l0 + 1u, top);
    let blend = level - f32(l0);
    var l = l0;
    var level_weight = 1.0 - blend;
    if (k >= 4u) {
        l = l1;
        level_weight = blend;
    }
    // PLANES: (0, 1), (0, 2), (1, 2).
    var a = at.x;
    var b = at.y;
    if (plane == 1u) {
        b = at.z;
    } else if (plane == 2u) {
        a = at.y;
        b = at.z;
    }
    let size = plane_side(planes, l);
    let cu = corner(a, size);
    let cv = corner(b, size);
    let wu = cu.z;
    let wv = cv.z;
    let c = k % 4u;
    var u = u32(cu.x);
    var v = u32(cv.x);
    var w = (1.0 - wu) * (1.0 - wv);
    if (c == 1u) {
        u = u32(cu.y);
        w = wu * (1.0 - wv);
    } else if (c == 2u) {
        v = u32(cv.y);
        w = (1.0 - wu) * wv;
    } else if (c == 3u) {
        u = u32(cu.y);
        v = u32(cv.y);
        w = wu * wv;
    }
    var offset = (plane * size * size + v * size + u) * planes.features;
    if (l > 0u) {
        offset = offset + plane_level_base(planes, l);
    }
    return Tap(l, offset, level_weight * w);
}

// Feature `f` read through a plane's `taps`: their weighted sum, in their order.
fn plane_feature(taps: ptr<function, array<Tap, TAPS_PER_PLANE>>, f: u32) -> f32 {
    var acc = 0.0;
    for (var k = 0u; k < TAPS_PER_PLANE; k = k + 1u) {
        let t = (*taps)[k];
        var texel: f32;
        if (t.level == 0u) {
            texel = model_params[t.offset + f];
        } else {
            texel = pyramid[t.offset + f];
        }
        acc = acc + t.weight * texel;
    }
    return acc;
}
