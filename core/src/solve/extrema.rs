//! A pixel's extremum lists, split by who needs them.
//!
//! Every later angle pairs its extrema with the reference (first) angle's twice: the ratio
//! votes and window sums (the index from the peak shift) and a pixel's order choice. The
//! image-wide statistics come from the index's sample of pixels
//! ([`super::fit_row::IndexSampling`]), so only those keep whole lists
//! ([`SampleExtrema`]: the current angle's, and the reference angle's but its last); every
//! pixel keeps the last [`HEAD`] extrema of both angles (the longest wavelengths, its lowest
//! orders, on a rig whose bands rise) and how many of each whole list lie inside the
//! reliable range ([`ExtremaHead`]), which its order search counts
//! ([`super::order::OrderContext::resolve_seen`]). Measured with the last four of the
//! reference angle against its whole list for every pixel's order: every figure `filmscope
//! eval` prints on the config scenes the same but one colour difference (0.064 -> 0.063
//! dE00), where choosing from the current angle alone lost valid pixels (99.9 -> 99.8 %,
//! 100 -> 99.9 %). With the current angle's last four as well (against its whole list, the
//! reference's head alone in both): paper-sample3 99.9 -> 99.8 % valid, zns-dispersive
//! 0.063 -> 0.064 dE00, every other figure the same.

use crate::track::{ExtremaHead, ExtremaList, Extremum, HEAD, MAX_EXTREMA};

/// The reference angle's extrema before its [`ExtremaHead`], kept by the pixels of the
/// index's sample: 34 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AnchorTail {
    items: [Extremum; MAX_EXTREMA - HEAD],
    len: u8,
}

impl AnchorTail {
    /// An empty tail.
    pub const EMPTY: Self = Self {
        items: [Extremum::ZERO; MAX_EXTREMA - HEAD],
        len: 0,
    };

    /// The tail of `list` (all but its last [`HEAD`]).
    pub fn of(list: &[Extremum]) -> Self {
        let mut tail = Self::EMPTY;
        let rest = &list[..list.len().saturating_sub(HEAD)];
        let n = rest.len().min(tail.items.len());
        tail.items[..n].copy_from_slice(&rest[..n]);
        tail.len = n as u8;
        tail
    }

    /// The extrema kept, in band order.
    pub fn extrema(&self) -> &[Extremum] {
        &self.items[..usize::from(self.len)]
    }

    /// The whole list in band order, in place: this tail, then `head`.
    pub fn whole<'a>(&'a self, head: &'a ExtremaHead) -> impl Iterator<Item = &'a Extremum> + 'a {
        self.extrema().iter().chain(head.extrema())
    }
}

/// What a pixel of the index's sample keeps besides its [`ExtremaHead`]s: the current
/// angle's whole list, how many of it have voted (the shard's `vote_rows`), and the
/// reference angle's extrema before its head: 78 bytes with padding.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SampleExtrema {
    /// Extrema at the current angle.
    pub current: ExtremaList,
    /// How many of `current` have voted; the tally votes the rest.
    pub voted: u8,
    /// The reference angle's extrema before its head.
    pub tail: AnchorTail,
}

/// The reference angle's extrema a pixel has, in place and in band order: the whole list
/// for a pixel of the index's sample (its `lists`), its `head` alone for another.
pub fn reference<'a>(
    head: &'a ExtremaHead,
    lists: Option<&'a SampleExtrema>,
) -> impl Iterator<Item = &'a Extremum> + 'a {
    lists.map_or(&AnchorTail::EMPTY, |l| &l.tail).whole(head)
}

impl SampleExtrema {
    /// Nothing kept.
    pub const EMPTY: Self = Self {
        current: ExtremaList::new(),
        voted: 0,
        tail: AnchorTail::EMPTY,
    };

    /// The current angle's extrema not voted yet.
    pub fn unvoted(&self) -> &[Extremum] {
        &self.current[usize::from(self.voted).min(self.current.len())..]
    }

    /// Starts an angle: no extrema, none voted.
    pub fn begin_angle(&mut self) {
        self.current.clear();
        self.voted = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::{ExtremaList, Kind};

    fn list(n: usize) -> ExtremaList {
        let mut l = ExtremaList::new();
        for k in 0..n {
            let kind = if k % 2 == 0 { Kind::Peak } else { Kind::Valley };
            l.push(Extremum::new(3.0 + 7.25 * k as f32, kind))
                .expect("room");
        }
        l
    }

    /// Split and joined again, every list length gives back its list.
    #[test]
    fn head_and_tail_join_to_the_whole_list() {
        for n in 0..=MAX_EXTREMA {
            let l = list(n);
            let head = ExtremaHead::of(&l);
            let tail = AnchorTail::of(&l);
            let mut whole = ExtremaList::new();
            for &e in tail.whole(&head) {
                whole.push(e).expect("room");
            }
            assert_eq!(whole, l, "{n} extrema");
        }
        assert_eq!(core::mem::size_of::<AnchorTail>(), 34);
        assert_eq!(core::mem::size_of::<SampleExtrema>(), 78);
    }
}
