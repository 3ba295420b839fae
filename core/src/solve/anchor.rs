//! The reference (first) angle's extrema, split by who needs them.
//!
//! Every later angle pairs its extrema with the reference angle's twice: the ratio votes and
//! window sums (the index from the peak shift) and a pixel's order choice. The image-wide
//! statistics come from the index's sample of pixels ([`super::fit_row::IndexSampling`]),
//! so only those keep the whole list; every pixel keeps its [`ANCHOR_HEAD`] last extrema (the
//! longest wavelengths, its lowest orders, on a rig whose bands rise) and how many of the
//! whole list lie inside the reliable range, which its order search counts
//! ([`super::order::OrderContext::resolve_seen`]). Measured with the last four, against the
//! whole list for every pixel's order: every figure `filmscope eval` prints on the config
//! scenes the same but one colour difference (0.064 -> 0.063 dE00), where choosing from
//! the current angle alone lost valid pixels (99.9 -> 99.8 %, 100 -> 99.9 %).

use crate::track::{Extremum, MAX_EXTREMA};

/// Extrema of the reference angle every pixel keeps.
pub const ANCHOR_HEAD: usize = 4;

/// The reference angle's last [`ANCHOR_HEAD`] extrema (band order) and the whole list's
/// count inside the reliable range: 10 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AnchorHead {
    items: [Extremum; ANCHOR_HEAD],
    len: u8,
    reliable: u8,
}

/// The reference angle's extrema before its [`AnchorHead`], kept by the pixels of the
/// index's sample: 34 bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AnchorTail {
    items: [Extremum; MAX_EXTREMA - ANCHOR_HEAD],
    len: u8,
}

impl AnchorHead {
    /// An empty head (no reference angle yet).
    pub const EMPTY: Self = Self {
        items: [Extremum::ZERO; ANCHOR_HEAD],
        len: 0,
        reliable: 0,
    };

    /// The head of `list`, of which `reliable` lie inside the reliable range.
    pub fn of(list: &[Extremum], reliable: usize) -> Self {
        let mut head = Self::EMPTY;
        let rest = &list[list.len().saturating_sub(ANCHOR_HEAD)..];
        head.items[..rest.len()].copy_from_slice(rest);
        head.len = rest.len() as u8;
        head.reliable = reliable.min(usize::from(u8::MAX)) as u8;
        head
    }

    /// The extrema kept, in band order.
    pub fn extrema(&self) -> &[Extremum] {
        &self.items[..usize::from(self.len)]
    }

    /// How many of the whole list lie inside the reliable range.
    pub fn reliable(&self) -> usize {
        usize::from(self.reliable)
    }
}

impl AnchorTail {
    /// An empty tail.
    pub const EMPTY: Self = Self {
        items: [Extremum::ZERO; MAX_EXTREMA - ANCHOR_HEAD],
        len: 0,
    };

    /// The tail of `list` (all but its last [`ANCHOR_HEAD`]).
    pub fn of(list: &[Extremum]) -> Self {
        let mut tail = Self::EMPTY;
        let rest = &list[..list.len().saturating_sub(ANCHOR_HEAD)];
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
    pub fn whole<'a>(&'a self, head: &'a AnchorHead) -> impl Iterator<Item = &'a Extremum> + 'a {
        self.extrema().iter().chain(head.extrema())
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

    /// Split and joined again, every list length gives back its list; the head holds the
    /// last extrema and the count it was given.
    #[test]
    fn head_and_tail_join_to_the_whole_list() {
        for n in 0..=MAX_EXTREMA {
            let l = list(n);
            let head = AnchorHead::of(&l, n + 1);
            let tail = AnchorTail::of(&l);
            let mut whole = ExtremaList::new();
            for &e in tail.whole(&head) {
                whole.push(e).expect("room");
            }
            assert_eq!(whole, l, "{n} extrema");
            assert_eq!(head.extrema(), &l[n.saturating_sub(ANCHOR_HEAD)..]);
            assert_eq!(head.reliable(), n + 1);
        }
        assert_eq!(AnchorHead::of(&list(3), 1000).reliable(), 255);
        assert_eq!(core::mem::size_of::<AnchorHead>(), 10);
        assert_eq!(core::mem::size_of::<AnchorTail>(), 34);
    }
}
