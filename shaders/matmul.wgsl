// C[m x n] (=|+=) A[m x k] · B[k x n], then an epilogue: + a row of a per-group matrix (row r
// adds row r / rows_per_group of it: a ray's term to each of its samples), + bias[col], ReLU, or
// the ReLU backward mask (x 1 where mask > 0, else 0).
//
// Operands live anywhere in their buffers (element offsets), stored row-major, each optionally
// transposed (stored n x k / k x m). Results are deterministic (no atomics): every output sums
// its k products in order, one after the other. A product may be split over k into `n_splits`
// partial products, split z summing k in [z * k_chunk, min(k, (z + 1) * k_chunk)) in order; the
// partials go to scratch (C's buffer, m * n floats apart) and `reduce_splits` adds them in order
// z = 0, 1, ... before the epilogue. That is how the weight gradients (m x n small, k = every
// sample of the batch) keep thousands of workgroups busy instead of a few hundred long loops.
//
// Two product entry points compute the same partial sums in the same order:
// - `tiled`: for hardware GPUs. A 64 x 64 output tile per workgroup of 256 invocations, each
//   owning a 4 x 4 block held in registers; 16-wide slices of k staged through workgroup memory
//   with loads where neighbouring invocations read neighbouring addresses whichever way an
//   operand is stored, then read back as vec4s.
// - `blocked`: for software adapters (lavapipe). A 4 x 4 block per invocation read straight from
//   the storage buffers, no workgroup memory or barriers, which lavapipe emulates per lane.
// Both walk row and column tiles in grid-stride loops, so a dispatch of at most 65535 groups per
// dimension covers any m and n.

// The uniform block `Params` is declared from the Rust struct `MatmulParams` (kernels/matmul.rs).

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> a: array<f32>;
@group(0) @binding(2) var<storage, read> b: array<f32>;
@group(0) @binding(3) var<storage, read_write> c: array<f32>;
// The ReLU-backward mask or the per-group matrix (one epilogue uses it at a time).
@group(0) @binding(4) var<storage, read> mask: array<f32>;

const FLAG_A_T: u32 = 1u;
const FLAG_B_T: u32 = 2u;
const FLAG_ACCUMULATE: u32 = 4u;
const FLAG_BIAS: u32 = 8u;
const FLAG_RELU: u32 = 16u;
const FLAG_MASK: u32 = 32u;
const FLAG_PARTIAL: u32 = 64u;
const FLAG_PER_GROUP: u32 = 128u;

// Element (row, kk) of A, 0 outside rows < m and kk < k_end.
fn load_a(row: u32, kk: u32, k_end: u32) -> f32 {
    if (row >= p.m || kk >= k_end) {
        return 0.0;
    }
    if ((p.flags & FLAG_A_T) != 0u) {
        return a[p.a_off + kk * p.a_ld + row];
    }
    return a[p.a_off + row * p.a_ld + kk];
}

// Element (kk, col) of B, 0 outside kk < k_end and col < n.
fn load_b(kk: u32, col: u32, k_end: u32) -> f32 {
    if (kk >= k_end || col >= p.n) {
        return 0.0;
    }
    if ((p.flags & FLAG_B_T) != 0u) {
        return b[p.b_off + col * p.k + kk];
    }
    return b[p.b_off + kk * p.n + col];
}

// Output (row, col) of split z with sum `sum`: the raw partial, or the epilogue.
fn store(row: u32, col: u32, z: u32, sum: f32) {
    if ((p.flags & FLAG_PARTIAL) != 0u) {
        c[p.c_off + z * p.m * p.n + row * p.n + col] = sum;
        return;
    }
    let idx = p.c_off + row * p.c_ld + col;
    var acc = sum;
    if ((p.flags & FLAG_ACCUMULATE) != 0u) {
        acc = c[idx] + acc;
    }
    if ((p.flags & FLAG_PER_GROUP) != 0u) {
        acc = acc + mask[p.mask_off + (row / p.rows_per_group) * p.n + col];
    }
    if ((p.flags & FLAG_BIAS) != 0u) {
        acc = acc + b[p.bias_off + col];
    }
    if ((p.flags & FLAG_RELU) != 0u) {
        acc = max(acc, 0.0);
    }
    if ((p.flags & FLAG_MASK) != 0u) {
        acc = select(0.0, acc, mask[p.mask_off + row * p.n + col] > 0.0);
    }
    c[idx] = acc;
}

// Stores the 4 x 4 block at (row0, col0) that lies inside the matrix.
fn store_block(row0: u32, col0: u32, z: u32, acc: array<vec4<f32>, 4>) {
    for (var i = 0u; i < 4u; i = i + 1u) {
        let row = row0 + i;
        if (row >= p.m) {
            break;
        }
        for (var j = 0u; j < 4u; j = j + 1u) {
            if (col0 + j < p.n) {
                store(row, col0 + j, z, acc[i][j]);
            }
        }
    }
}

const TILE: u32 = 64u;
const SLICE: u32 = 16u;
// A's slice, k-major: sa[kk * 16 + r / 4][r % 4] is (row0 + r, kt + kk). B's likewise, by column.
// Every element is written before it is read (no zero initialisation needed).
var<workgroup> sa: array<vec4<f32>, 256>;
var<workgroup> sb: array<vec4<f32>, 256>;

@compute @workgroup_size(256)
fn tiled(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    // This invocation's 4 x 4 block: rows 4 ty.., columns 4 tx.. of the tile.
    let tx = li % 16u;
    let ty = li / 16u;
    let z = wg.z;
    let k0 = z * p.k_chunk;
    let k1 = min(p.k, k0 + p.k_chunk);
    let row_tiles = (p.m + TILE - 1u) / TILE;
    let col_tiles = (p.n + TILE - 1u) / TILE;
    let a_t = (p.flags & FLAG_A_T) != 0u;
    let b_t = (p.flags & FLAG_B_T) != 0u;
    for (var ct = wg.x; ct < col_tiles; ct = ct + nwg.x) {
    let col0 = ct * TILE;
    for (var rt = wg.y; rt < row_tiles; rt = rt + nwg.y) {
        let row0 = rt * TILE;
        var acc0 = vec4<f32>(0.0);
        var acc1 = vec4<f32>(0.0);
        var acc2 = vec4<f32>(0.0);
        var acc3 = vec4<f32>(0.0);
        for (var kt = k0; kt < k1; kt = kt + SLICE) {
            // 1024 elements of each operand's slice, 4 per invocation. Neighbouring invocations
            // take neighbouring elements along the operand's stored rows.
            for (var e = 0u; e < 4u; e = e + 1u) {
                let lin = e * 256u + li;
                var r = lin / SLICE;
                var ka = lin % SLICE;
                if (a_t) {
                    r = lin % TILE;
                    ka = lin / TILE;
                }
                sa[ka * 16u + r / 4u][r % 4u] = load_a(row0 + r, kt + ka, k1);
                var col = lin % TILE;
                var kb = lin / TILE;
                if (b_t) {
                    col = lin / SLICE;
                    kb = lin % SLICE;
                }
                sb[kb * 16u + col / 4u][col % 4u] = load_b(kt + kb, col0 + col, k1);
            }
            workgroupBarrier();
            for (var kk = 0u; kk < SLICE; kk = kk + 1u) {
                let av = sa[kk * 16u + ty];
                let bv = sb[kk * 16u + tx];
                acc0 = acc0 + av.x * bv;
                acc1 = acc1 + av.y * bv;
                acc2 = acc2 + av.z * bv;
                acc3 = acc3 + av.w * bv;
            }
            workgroupBarrier();
        }
        store_block(row0 + 4u * ty, col0 + 4u * tx, z, array<vec4<f32>, 4>(acc0, acc1, acc2, acc3));
    }
    }
}

@compute @workgroup_size(8, 8)
fn blocked(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let z = gid.z;
    let k0 = z * p.k_chunk;
    let k1 = min(p.k, k0 + p.k_chunk);
    // Element (r, kk) of A is at a_off + r * a_rs + kk * a_ks; (kk, col) of B at b_off + kk * b_ks + col * b_cs.
    var a_rs = p.a_ld;
    var a_ks = 1u;
    if ((p.flags & FLAG_A_T) != 0u) {
        a_rs = 1u;
        a_ks = p.a_ld;
    }
    var b_ks = p.n;
    var b_cs = 1u;
    if ((p.flags & FLAG_B_T) != 0u) {
        b_ks = 1u;
        b_cs = p.k;
    }
    let rows_per_pass = nwg.y * 8u * 4u;
    let cols_per_pass = nwg.x * 8u * 4u;
    for (var col0 = gid.x * 4u; col0 < p.n; col0 = col0 + cols_per_pass) {
    // Columns past the edge read the last valid one (their results are not stored).
    let cols = min(vec4<u32>(col0, col0 + 1u, col0 + 2u, col0 + 3u), vec4<u32>(p.n - 1u));
    for (var row0 = gid.y * 4u; row0 < p.m; row0 = row0 + rows_per_pass) {
        // Rows past the edge read the last valid one likewise, so the loop has no bounds checks.
        let rows = min(vec4<u32>(row0, row0 + 1u, row0 + 2u, row0 + 3u), vec4<u32>(p.m - 1u));
        var ia = vec4<u32>(p.a_off) + rows * a_rs + vec4<u32>(k0 * a_ks);
        var ib = vec4<u32>(p.b_off) + cols * b_cs + vec4<u32>(k0 * b_ks);
        var acc0 = vec4<f32>(0.0);
        var acc1 = vec4<f32>(0.0);
        var acc2 = vec4<f32>(0.0);
        var acc3 = vec4<f32>(0.0);
        for (var kk = k0; kk < k1; kk = kk + 1u) {
            let av = vec4<f32>(a[ia.x], a[ia.y], a[ia.z], a[ia.w]);
            let bv = vec4<f32>(b[ib.x], b[ib.y], b[ib.z], b[ib.w]);
            acc0 = acc0 + av.x * bv;
            acc1 = acc1 + av.y * bv;
            acc2 = acc2 + av.z * bv;
            acc3 = acc3 + av.w * bv;
            ia = ia + vec4<u32>(a_ks);
            ib = ib + vec4<u32>(b_ks);
        }
        store_block(row0, col0, z, array<vec4<f32>, 4>(acc0, acc1, acc2, acc3));
    }
    }
}

// C = epilogue(sum over z = 0, 1, ... of the partial products in `a` from a_off, m * n floats
// apart): the second pass of a split product, one invocation per output.
@compute @workgroup_size(WORKGROUP)
fn reduce_splits(@builtin(global_invocation_id) gid: vec3<u32>) {
    let idx = gid.y * (p.groups_x * WORKGROUP) + gid.x;
    let total = p.m * p.n;
    if (idx >= total) {
        return;
    }
    var sum = 0.0;
    for (var z = 0u; z < p.n_splits; z = z + 1u) {
        sum = sum + a[p.a_off + z * total + idx];
    }
    store(idx / p.n, idx % p.n, 0u, sum);
}
