//! The pixels of a shard whose order an angle's end could not call (ties), as a set of bits.
//!
//! At an early angle's end most of a sensor's pixels can be ties (two close angles seldom
//! tell the orders apart): as a list of indices they took 8 bytes a pixel, 34 MB of a
//! 2048 x 2048 sweep's peak heap (heaptrack); as bits they take an eighth of a byte.

/// A set of pixel indices of one shard, below the count it was made for.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct TieSet {
    words: Vec<u64>,
    /// The pixels it is for.
    pixels: usize,
}

impl TieSet {
    /// An empty set for the pixels `0..pixels`.
    pub fn new(pixels: usize) -> Self {
        Self {
            words: vec![0; pixels.div_ceil(64)],
            pixels,
        }
    }

    /// Adds pixel `i` (one beyond the pixels it was made for is left out).
    pub fn insert(&mut self, i: usize) {
        if i < self.pixels {
            self.words[i / 64] |= 1 << (i % 64);
        }
    }

    /// The pixels in the set, in increasing order (and, reversed, in decreasing order).
    pub fn iter(&self) -> impl DoubleEndedIterator<Item = usize> + '_ {
        self.words
            .iter()
            .enumerate()
            .filter(|(_, &w)| w != 0)
            .flat_map(|(k, &w)| {
                (0..64)
                    .filter(move |b| (w >> b) & 1 != 0)
                    .map(move |b| k * 64 + b)
            })
    }
}

#[cfg(test)]
mod tests {
    use super::TieSet;

    #[test]
    fn a_tie_set_gives_back_its_pixels_in_order_both_ways() {
        let pixels = [0, 1, 63, 64, 65, 127, 128, 1000, 4095];
        let mut set = TieSet::new(4096);
        for &i in pixels.iter().rev() {
            set.insert(i);
        }
        set.insert(1000);
        set.insert(4096);
        assert_eq!(set.iter().collect::<Vec<_>>(), pixels);
        let mut rev = pixels;
        rev.reverse();
        assert_eq!(set.iter().rev().collect::<Vec<_>>(), rev);
        assert_eq!(TieSet::new(10).iter().count(), 0);
        // Beyond the pixels, inside the last word: left out too.
        let mut short = TieSet::new(10);
        short.insert(9);
        short.insert(20);
        assert_eq!(short.iter().collect::<Vec<_>>(), [9]);
        // A forward and a backward walk meet without a pixel given twice.
        let mut it = set.iter();
        let (a, b) = (it.next(), it.next_back());
        assert_eq!((a, b), (Some(0), Some(4095)));
        assert_eq!(it.count(), pixels.len() - 2);
    }
}
