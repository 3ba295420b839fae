//! A worker's held bands: the rows of a block of bands that wait to be fed to the shard's
//! pixels, in one buffer sized once for the shard.
//!
//! The calibrate stage sends each band's rows as a message of packed samples
//! ([`filmscope_core::track::pack_sample`], 2 bytes a sample); a worker copies them into its
//! [`HeldBlock`] and drops the message at once, so what a block holds lives in one allocation
//! the worker owns rather than in thousands of small ones spread over the allocator's arenas.
//! That allocation is sized once for the sweep ([`HeldBlock::size_for`]) and given back
//! after its last angle ([`HeldBlock::release`]), before the coordinator allocates the maps'
//! results, so that the two do not add up in the sweep's peak memory (`filmscope bench`'s
//! peak RSS).

/// Rows of one band held: the band, the first image row, the number of rows and where their
/// samples start in the block's buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeldRows {
    /// Band index within the angle.
    pub band: u16,
    /// First image row.
    pub row: u32,
    /// Rows held.
    pub rows: u32,
    /// Offset of the first sample in the buffer.
    offset: usize,
}

impl HeldRows {
    /// The image rows held.
    pub fn image_rows(&self) -> core::ops::Range<usize> {
        self.row as usize..(self.row + self.rows) as usize
    }
}

/// The rows a worker holds, in the order they arrived, and their packed samples.
#[derive(Debug, Default)]
pub struct HeldBlock {
    entries: Vec<HeldRows>,
    samples: Vec<u16>,
    /// Samples the buffer is sized for.
    capacity: usize,
}

impl HeldBlock {
    /// Sizes the buffer for `samples` packed samples (a block of bands of the shard's rows):
    /// allocates it if it was released or is smaller, gives it back and allocates a smaller
    /// one if it is larger (what it holds is forgotten then; call it between blocks).
    pub fn size_for(&mut self, samples: usize) {
        if self.samples.capacity() > samples {
            self.release();
        }
        self.capacity = samples;
        self.samples
            .reserve(samples.saturating_sub(self.samples.len()));
    }

    /// Whether `samples` more samples fit in the buffer as sized.
    pub fn fits(&self, samples: usize) -> bool {
        self.samples.len() + samples <= self.capacity
    }

    /// Holds `rows` rows of band `band` from image row `row` on (`values`: their packed
    /// samples, row after row). Past the size the buffer grows: callers feed the block first
    /// ([`HeldBlock::fits`]).
    pub fn push(&mut self, band: u16, row: u32, rows: u32, values: &[u16]) {
        self.entries.push(HeldRows {
            band,
            row,
            rows,
            offset: self.samples.len(),
        });
        self.samples.extend_from_slice(values);
    }

    /// The rows held, in the order they arrived.
    pub fn entries(&self) -> &[HeldRows] {
        &self.entries
    }

    /// The band of the rows that arrived last.
    pub fn last_band(&self) -> Option<u16> {
        self.entries.last().map(|e| e.band)
    }

    /// Row `k` (from the entry's first) of the held rows `e`, `width` samples.
    pub fn row(&self, e: &HeldRows, k: usize, width: usize) -> &[u16] {
        let start = e.offset + k * width;
        &self.samples[start..start + width]
    }

    /// Forgets what is held; the buffer stays allocated for the next block.
    pub fn clear(&mut self) {
        self.entries.clear();
        self.samples.clear();
    }

    /// Forgets what is held and gives the buffer back to the allocator (the next
    /// [`HeldBlock::size_for`] allocates it again).
    pub fn release(&mut self) {
        self.entries = Vec::new();
        self.samples = Vec::new();
        self.capacity = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_come_back_in_arrival_order_and_release_frees_the_buffer() {
        let mut h = HeldBlock::default();
        h.size_for(12);
        assert!(h.fits(12) && !h.fits(13));
        h.push(3, 10, 2, &[1, 2, 3, 4]);
        h.push(4, 10, 1, &[5, 6]);
        assert!(h.fits(6) && !h.fits(7));
        assert_eq!(h.last_band(), Some(4));
        let e = h.entries().to_vec();
        assert_eq!(e.len(), 2);
        assert_eq!(e[0].image_rows(), 10..12);
        assert_eq!(h.row(&e[0], 1, 2), &[3, 4]);
        assert_eq!(h.row(&e[1], 0, 2), &[5, 6]);
        h.clear();
        assert!(h.entries().is_empty() && h.fits(12));
        assert!(h.samples.capacity() >= 12);
        h.release();
        assert_eq!(h.samples.capacity(), 0);
        assert!(!h.fits(1));
        h.size_for(4);
        assert!(h.fits(4));
        // Sized smaller: a smaller buffer.
        h.size_for(100);
        assert!(h.samples.capacity() >= 100);
        h.size_for(10);
        assert!(h.fits(10) && !h.fits(11));
        assert!(h.samples.capacity() < 100);
    }
}
