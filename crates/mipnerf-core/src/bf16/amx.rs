use std::arch::asm;

use super::{BLOCK, K_STEP};

/// Whether this CPU and operating system run the AMX kernel, and if not, why.
pub(super) fn detect() -> Result<(), String> {
    {
        // CPUID leaf 7 exists when leaf 0 reports a maximum leaf of at least 7.
        let edx = if std::arch::x86_64::__cpuid(0).eax >= 7 { std::arch::x86_64::__cpuid_count(7, 0).edx } else { 0 };
        let (tile, bf16) = (edx & (1 << 24) != 0, edx & (1 << 22) != 0);
        if !tile || !bf16 {
            return Err(format!("this CPU lacks {} (Intel AMX)", if tile { "amx_bf16" } else { "amx_tile" }));
        }
        // The packing converts to bf16 with AVX-512, which the AVX-512 kernel's check covers.
        if let Err(why) = super::Bf16Kernel::Avx512.check() {
            return Err(format!("this CPU has AMX, but for the conversions to bf16 {why}"));
        }
        if !cfg!(target_os = "linux") {
            return Err("AMX tiles are only enabled on Linux in this build".into());
        }
        let ret = request_tile_permission();
        if ret != 0 {
            return Err(format!(
                "the operating system refused the AMX tile state (arch_prctl returned {ret}; Linux 5.16 or later \
                 is needed)"
            ));
        }
        Ok(())
    }
}

/// `arch_prctl(ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA)`: Linux grants the process the AMX
/// tile data state (required before the first tile instruction, or the process is killed).
#[cfg(all(target_arch = "x86_64", target_os = "linux"))]
fn request_tile_permission() -> i64 {
    const SYS_ARCH_PRCTL: i64 = 158;
    const ARCH_REQ_XCOMP_PERM: i64 = 0x1023;
    const XFEATURE_XTILEDATA: i64 = 18;
    let ret: i64;
    // SAFETY: a raw Linux system call that takes two integers and touches no memory of ours;
    // rcx and r11 are clobbered by `syscall` and declared so.
    unsafe {
        asm!(
            "syscall",
            inlateout("rax") SYS_ARCH_PRCTL => ret,
            in("rdi") ARCH_REQ_XCOMP_PERM,
            in("rsi") XFEATURE_XTILEDATA,
            lateout("rcx") _,
            lateout("r11") _,
            options(nostack),
        );
    }
    ret
}
#[cfg(all(target_arch = "x86_64", not(target_os = "linux")))]
fn request_tile_permission() -> i64 {
    -1
}

/// A 32 x 32 block of `c` on cache lines (tile rows that straddle two lines load and store
/// slowly: [`crate::lines::Lines`]).
#[repr(C, align(64))]
struct ScratchBlock([f32; BLOCK * BLOCK]);

/// Tile configuration (palette 1): 8 tiles of 16 rows x 64 bytes.
#[repr(C, align(64))]
struct TileConfig([u8; 64]);

impl TileConfig {
    fn all_16x64() -> Self {
        let mut c = [0u8; 64];
        c[0] = 1;
        for t in 0..8 {
            c[16 + 2 * t] = 64;
            c[48 + t] = 16;
        }
        Self(c)
    }
}

/// The packed operands (`a` and `b` together, bf16) above which a product runs k in chunks of
/// [`K_CHUNK_TILES`]: the size of one core's L2 cache on the Xeons with AMX (2 MiB). Past it, each
/// 32 x 32 block of `c` streams its strips of `a` and `b` (32 rows or columns by the whole of k)
/// from farther than L2 again for every block beside it. This is the weight gradient over the
/// paper preset's 8,192-row chunks (`docs/results/amx-k-chunks/`).
const WHOLE_K_MAX_BYTES: usize = 2 << 20;

/// Tiles of k (32 values each) per chunk when k runs in chunks: 256 values of k, strips of 16
/// KiB of `a` and of `b` per block of `c`, which stay in L1 across the blocks beside it.
const K_CHUNK_TILES: usize = 8;

/// `c (m x n, row-major) = [c +] A · B` from the packed operands ([`super::a_index`],
/// [`super::b_index`]). Tiles: tmm0..3 accumulate a 32 x 32 block of `c`, tmm4/5 hold two
/// 16-row tiles of `a`, tmm6/7 two 16-column tiles of `b`. A block inside `c` is loaded
/// (when accumulating) and stored in place; a block on the ragged edge goes through a
/// scratch block. Where the packed operands outgrow [`WHOLE_K_MAX_BYTES`], k runs in chunks of
/// [`K_CHUNK_TILES`] tiles, every block of `c` stored after one chunk and loaded again for the
/// next: the same multiply-adds in the same order on the same f32 accumulators, so the same bits.
pub(super) fn product(c: &mut [f32], a: &[u16], b: &[u32], shape: super::PackedShape) {
    super::assert_packed(super::Bf16Kernel::Amx, c, a.len(), b, shape);
    let super::PackedShape { m, n, mp, kp, np, accumulate } = shape;
    let cfg = TileConfig::all_16x64();
    let k_tiles = kp / K_STEP;
    let mut scratch = ScratchBlock([0f32; BLOCK * BLOCK]);
    let scratch = &mut scratch.0;
    let operand_bytes = 2 * kp * (mp + np);
    let chunk_tiles = if operand_bytes > WHOLE_K_MAX_BYTES { K_CHUNK_TILES } else { k_tiles.max(1) };
    // SAFETY: the process holds the tile permission (the check above), and the
    // configuration is a valid palette-1 layout; no other code in this program uses tiles.
    unsafe { asm!("ldtilecfg [{}]", in(reg) cfg.0.as_ptr(), options(nostack, readonly)) };
    for k0 in (0..k_tiles.max(1)).step_by(chunk_tiles) {
        // After the first chunk, each block continues from what the last chunk stored.
        let accumulate = accumulate || k0 > 0;
        let k_range = k0..(k0 + chunk_tiles).min(k_tiles);
        for i0 in (0..mp).step_by(BLOCK) {
            for j0 in (0..np).step_by(BLOCK) {
                let inside = i0 + BLOCK <= m && j0 + BLOCK <= n;
                // The block's top-left f32 and row stride in bytes: in `c`, or in the scratch.
                let (base, stride) = if inside {
                    (c[i0 * n + j0..].as_mut_ptr(), n * 4)
                } else {
                    if accumulate {
                        let cols = BLOCK.min(n.saturating_sub(j0));
                        for r in 0..BLOCK.min(m.saturating_sub(i0)) {
                            scratch[r * BLOCK..r * BLOCK + cols].copy_from_slice(&c[(i0 + r) * n + j0..][..cols]);
                        }
                    }
                    (scratch.as_mut_ptr(), BLOCK * 4)
                };
                // SAFETY: 32 rows x 32 f32 at `stride` from `base` lie inside `c` (the block is
                // inside: i0 + 32 <= m, j0 + 32 <= n) or inside the 32 x 32 scratch.
                unsafe {
                    if accumulate {
                        accumulators::<false>(base, stride);
                    } else {
                        asm!(
                            "tilezero tmm0",
                            "tilezero tmm1",
                            "tilezero tmm2",
                            "tilezero tmm3",
                            options(nostack, nomem)
                        );
                    }
                }
                for kt in k_range.clone() {
                    let pa = a[super::a_index(i0, kt * K_STEP, kp)..].as_ptr();
                    let pa1 = a[super::a_index(i0 + 16, kt * K_STEP, kp)..].as_ptr();
                    let pb = b[super::b_index(kt * K_STEP / 2, j0, kp)..].as_ptr();
                    let pb1 = b[super::b_index(kt * K_STEP / 2, j0 + 16, kp)..].as_ptr();
                    // SAFETY: each load reads one packed tile, 16 rows of 64 contiguous bytes
                    // (1 KiB) from its first element: a tiles (rows i0.. and i0 + 16.., k tile
                    // kt) and b tiles (pair rows 16 kt.., columns j0.. and j0 + 16..) lie inside
                    // the packed buffers, whose sizes are asserted above.
                    unsafe {
                        asm!(
                            "tileloadd tmm4, [{pa} + {s}]",
                            "tileloadd tmm6, [{pb} + {s}]",
                            "tdpbf16ps tmm0, tmm4, tmm6",
                            "tileloadd tmm7, [{pb1} + {s}]",
                            "tdpbf16ps tmm1, tmm4, tmm7",
                            "tileloadd tmm5, [{pa1} + {s}]",
                            "tdpbf16ps tmm2, tmm5, tmm6",
                            "tdpbf16ps tmm3, tmm5, tmm7",
                            pa = in(reg) pa,
                            pa1 = in(reg) pa1,
                            pb = in(reg) pb,
                            pb1 = in(reg) pb1,
                            s = in(reg) 64usize,
                            options(nostack, readonly),
                        );
                    }
                }
                // SAFETY: as for the loads of the block above.
                unsafe { accumulators::<true>(base, stride) };
                if !inside {
                    let cols = BLOCK.min(n.saturating_sub(j0));
                    for r in 0..BLOCK.min(m.saturating_sub(i0)) {
                        c[(i0 + r) * n + j0..][..cols].copy_from_slice(&scratch[r * BLOCK..r * BLOCK + cols]);
                    }
                }
            }
        }
    }
    // SAFETY: returns the tile state to its initial configuration.
    unsafe { asm!("tilerelease", options(nostack, nomem)) };
}

/// Moves the four accumulator tiles (tmm0..3, the 32 x 32 block of `c` in quarters of 16 x 16)
/// between the tiles and the block of f32 at `base`, rows `stride` bytes apart: stores them
/// with `STORE`, else loads them.
///
/// # Safety
/// The tiles are configured ([`TileConfig::all_16x64`]), and 32 rows of 32 `f32` at `stride`
/// bytes from `base` lie inside one buffer (written with `STORE`, read without).
#[inline(always)]
unsafe fn accumulators<const STORE: bool>(base: *mut f32, stride: usize) {
    // SAFETY: the caller's: each quarter's 16 rows of 64 bytes lie inside the block.
    unsafe {
        let (p0, p1, p2, p3) = (base, base.add(16), base.add(16 * stride / 4), base.add(16 * stride / 4 + 16));
        if STORE {
            asm!(
                "tilestored [{p0} + {s}], tmm0",
                "tilestored [{p1} + {s}], tmm1",
                "tilestored [{p2} + {s}], tmm2",
                "tilestored [{p3} + {s}], tmm3",
                p0 = in(reg) p0,
                p1 = in(reg) p1,
                p2 = in(reg) p2,
                p3 = in(reg) p3,
                s = in(reg) stride,
                options(nostack),
            );
        } else {
            asm!(
                "tileloadd tmm0, [{p0} + {s}]",
                "tileloadd tmm1, [{p1} + {s}]",
                "tileloadd tmm2, [{p2} + {s}]",
                "tileloadd tmm3, [{p3} + {s}]",
                p0 = in(reg) p0,
                p1 = in(reg) p1,
                p2 = in(reg) p2,
                p3 = in(reg) p3,
                s = in(reg) stride,
                options(nostack, readonly),
            );
        }
    }
}
