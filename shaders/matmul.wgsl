// C[m x n] (=|+=) A[m x k] · B[k x n], then optionally + bias[col] and ReLU.
//
// Operands live anywhere in their buffers (element offsets), stored row-major, each optionally
// transposed (stored n x k / k x m). Every output element sums over k in order 0..k, so results
// are deterministic (no atomics). The bias, if any, is read from B's buffer (the parameters).
//
// Two entry points compute the same thing:
// - `main`: 16 x 16 output tiles per workgroup, staged through workgroup memory in 16-wide slices
//   of k (the classic kernel for hardware GPUs);
// - `blocked`: a 4 x 4 block of outputs per invocation read straight from the storage buffers, no
//   workgroup memory or barriers: on software rasterisers (lavapipe), where workgroup memory and
//   barriers are emulated per lane, it is several times faster.

struct Params {
    m: u32,
    k: u32,
    n: u32,
    // bit 0: A transposed; bit 1: B transposed; bit 2: accumulate into C; bit 3: add bias;
    // bit 4: ReLU after the bias.
    flags: u32,
    a_off: u32,
    b_off: u32,
    c_off: u32,
    bias_off: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read> b: array<f32>;
@group(0) @binding(3) var<storage, read_write> c: array<f32>;

const TILE: u32 = 16u;
var<workgroup> tile_a: array<array<f32, 16>, 16>;
var<workgroup> tile_b: array<array<f32, 16>, 16>;

fn load_a(row: u32, col: u32) -> f32 {
    if (row >= p.m || col >= p.k) {
        return 0.0;
    }
    if ((p.flags & 1u) != 0u) {
        return a[p.a_off + col * p.m + row];
    }
    return a[p.a_off + row * p.k + col];
}

fn load_b(row: u32, col: u32) -> f32 {
    if (row >= p.k || col >= p.n) {
        return 0.0;
    }
    if ((p.flags & 2u) != 0u) {
        return b[p.b_off + col * p.k + row];
    }
    return b[p.b_off + row * p.n + col];
}

@compute @workgroup_size(16, 16)
fn main(@builtin(workgroup_id) wg: vec3<u32>, @builtin(local_invocation_id) lid: vec3<u32>) {
    let row = wg.y * TILE + lid.y;
    let col = wg.x * TILE + lid.x;
    var acc = 0.0;
    let n_tiles = (p.k + TILE - 1u) / TILE;
    for (var t = 0u; t < n_tiles; t = t + 1u) {
        tile_a[lid.y][lid.x] = load_a(row, t * TILE + lid.x);
        tile_b[lid.y][lid.x] = load_b(t * TILE + lid.y, col);
        workgroupBarrier();
        for (var i = 0u; i < TILE; i = i + 1u) {
            acc = acc + tile_a[lid.y][i] * tile_b[i][lid.x];
        }
        workgroupBarrier();
    }
    if (row >= p.m || col >= p.n) {
        return;
    }
    store(row, col, acc);
}

// The epilogue of output (row, col) with sum `acc`.
fn store(row: u32, col: u32, sum: f32) {
    let idx = p.c_off + row * p.n + col;
    var acc = sum;
    if ((p.flags & 4u) != 0u) {
        acc = c[idx] + acc;
    }
    if ((p.flags & 8u) != 0u) {
        acc = acc + b[p.bias_off + col];
    }
    if ((p.flags & 16u) != 0u) {
        acc = max(acc, 0.0);
    }
    c[idx] = acc;
}

@compute @workgroup_size(8, 8)
fn blocked(@builtin(global_invocation_id) gid: vec3<u32>) {
    let row0 = gid.y * 4u;
    let col0 = gid.x * 4u;
    if (row0 >= p.m || col0 >= p.n) {
        return;
    }
    // Rows and columns past the edge read the last valid one (their results are not stored), so
    // the loop has no bounds checks.
    let rows = min(vec4<u32>(row0, row0 + 1u, row0 + 2u, row0 + 3u), vec4<u32>(p.m - 1u));
    let cols = min(vec4<u32>(col0, col0 + 1u, col0 + 2u, col0 + 3u), vec4<u32>(p.n - 1u));
    // Element (r, kk) of A is at a_off + r * a_rs + kk * a_ks; (kk, col) of B at b_off + kk * b_ks + col * b_cs.
    var a_rs = p.k;
    var a_ks = 1u;
    if ((p.flags & 1u) != 0u) {
        a_rs = 1u;
        a_ks = p.m;
    }
    var b_ks = p.n;
    var b_cs = 1u;
    if ((p.flags & 2u) != 0u) {
        b_ks = 1u;
        b_cs = p.k;
    }
    var ia = vec4<u32>(p.a_off) + rows * a_rs;
    var ib = vec4<u32>(p.b_off) + cols * b_cs;
    var acc0 = vec4<f32>(0.0);
    var acc1 = vec4<f32>(0.0);
    var acc2 = vec4<f32>(0.0);
    var acc3 = vec4<f32>(0.0);
    for (var kk = 0u; kk < p.k; kk = kk + 1u) {
        let av = vec4<f32>(a[ia.x], a[ia.y], a[ia.z], a[ia.w]);
        let bv = vec4<f32>(b[ib.x], b[ib.y], b[ib.z], b[ib.w]);
        acc0 = acc0 + av.x * bv;
        acc1 = acc1 + av.y * bv;
        acc2 = acc2 + av.z * bv;
        acc3 = acc3 + av.w * bv;
        ia = ia + vec4<u32>(a_ks);
        ib = ib + vec4<u32>(b_ks);
    }
    let accs = array<vec4<f32>, 4>(acc0, acc1, acc2, acc3);
    for (var i = 0u; i < 4u; i = i + 1u) {
        let row = row0 + i;
        if (row >= p.m) {
            break;
        }
        for (var j = 0u; j < 4u; j = j + 1u) {
            if (col0 + j < p.n) {
                store(row, col0 + j, accs[i][j]);
            }
        }
    }
}
