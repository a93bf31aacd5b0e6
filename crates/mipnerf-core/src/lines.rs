//! A growable buffer whose first element starts a 64-byte cache line.

use std::ops::{Deref, DerefMut};

/// The bytes of a cache line, and of one row of an AMX tile.
const LINE: usize = 64;

/// A `Vec<T>` whose elements start on a 64-byte boundary: the packed bf16 operands and the MLP's
/// activations and gradients, which the products read and write. An AMX tile row (64 bytes) or
/// an AVX-512 vector that straddles two cache lines is a split access; on an Emerald Rapids Xeon
/// the AMX kernel ran 1.2x to 1.5x slower with its output 16 bytes past a line than on one
/// (`docs/results/amx-alignment/`), and `malloc` gives 16-byte alignment (a large block, from
/// `mmap`, starts 16 bytes past a line). Safe code only: the buffer over-allocates by a line and
/// starts at the first aligned element.
#[derive(Clone, Debug, Default)]
pub(crate) struct Lines<T> {
    raw: Vec<T>,
    start: usize,
    len: usize,
}

impl<T: Copy + Default> Lines<T> {
    /// Sets the length to `len` as `Vec::resize` does: new elements are `value`, the others keep
    /// theirs.
    pub(crate) fn resize(&mut self, len: usize, value: T) {
        if len <= self.len {
            self.len = len;
            return;
        }
        if self.start + len > self.raw.len() {
            let per_line = (LINE / std::mem::size_of::<T>().max(1)).max(1);
            let mut raw = vec![value; len + per_line];
            let start = aligned_start(&raw);
            raw[start..start + self.len].copy_from_slice(&self.raw[self.start..self.start + self.len]);
            (self.raw, self.start) = (raw, start);
        } else {
            self.raw[self.start + self.len..self.start + len].fill(value);
        }
        self.len = len;
    }

    /// A buffer of `len` copies of `value`.
    #[cfg(test)]
    pub(crate) fn filled(len: usize, value: T) -> Self {
        let mut lines = Self::default();
        lines.resize(len, value);
        lines
    }

    /// Empties the buffer, keeping its allocation.
    pub(crate) fn clear(&mut self) {
        self.len = 0;
    }
}

/// The index of `raw`'s first element on a 64-byte boundary (sizes of `T` that divide 64).
fn aligned_start<T>(raw: &[T]) -> usize {
    let size = std::mem::size_of::<T>().max(1);
    let address = raw.as_ptr() as usize;
    (LINE - address % LINE) % LINE / size
}

impl<T> Deref for Lines<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        &self.raw[self.start..self.start + self.len]
    }
}

impl<T> DerefMut for Lines<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        &mut self.raw[self.start..self.start + self.len]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_start_on_a_cache_line_and_resize_as_a_vec_does() {
        let (mut lines, mut vec) = (Lines::<u16>::default(), Vec::<u16>::new());
        for (step, len) in [5usize, 3, 40, 40, 7, 1000, 2, 70_000, 10].into_iter().enumerate() {
            lines.resize(len, step as u16);
            vec.resize(len, step as u16);
            for (i, x) in lines.iter_mut().enumerate() {
                *x = x.wrapping_add(i as u16);
            }
            for (i, x) in vec.iter_mut().enumerate() {
                *x = x.wrapping_add(i as u16);
            }
            assert_eq!(&lines[..], &vec[..], "length {len}");
            if len > 0 {
                assert_eq!(lines.as_ptr() as usize % LINE, 0, "length {len}");
            }
        }
        lines.clear();
        lines.resize(3, 9);
        assert_eq!(&lines[..], &[9, 9, 9]);
        let mut pairs = Lines::<u32>::default();
        pairs.resize(100, 1);
        assert_eq!(pairs.as_ptr() as usize % LINE, 0);
    }
}
