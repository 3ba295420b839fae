//! Where the tracker puts the extrema it finds: a pixel's whole list at one angle, or only
//! its last extrema and their counts.

use super::{Extremum, MAX_EXTREMA, WINDOW};

/// A pixel's extrema at one angle as the tracker confirms them, in increasing band order.
/// A sink holds at most [`MAX_EXTREMA`]; past that `push` hands the extremum back, and
/// the sink's owner flags the overflow.
pub trait ExtremumSink {
    /// The last extremum taken, if any.
    fn last_extremum(&self) -> Option<Extremum>;
    /// Takes `e`, or hands it back if [`MAX_EXTREMA`] came already.
    fn push(&mut self, e: Extremum) -> Result<(), Extremum>;
}

/// The sinks of a block's lanes (the row blocks' `TrackerLanes::push`): lane `i`'s extrema
/// go to sink `i`; a lane without one (a padding lane) drops them.
pub trait LaneSinks {
    /// [`ExtremumSink::last_extremum`] of lane `i`.
    fn last_at(&self, i: usize) -> Option<Extremum>;
    /// [`ExtremumSink::push`] to lane `i`.
    fn push_at(&mut self, i: usize, e: Extremum) -> Result<(), Extremum>;
}

impl<S: ExtremumSink> LaneSinks for [S] {
    #[inline]
    fn last_at(&self, i: usize) -> Option<Extremum> {
        self.get(i).and_then(ExtremumSink::last_extremum)
    }

    #[inline]
    fn push_at(&mut self, i: usize, e: Extremum) -> Result<(), Extremum> {
        self.get_mut(i).map_or(Ok(()), |s| s.push(e))
    }
}

/// Lane `i` of `sinks` as one sink (what the scalar tracker takes).
pub(super) struct Lane<'a, S: LaneSinks + ?Sized> {
    /// The block's sinks.
    pub sinks: &'a mut S,
    /// The lane.
    pub i: usize,
}

impl<S: LaneSinks + ?Sized> ExtremumSink for Lane<'_, S> {
    #[inline]
    fn last_extremum(&self) -> Option<Extremum> {
        self.sinks.last_at(self.i)
    }

    #[inline]
    fn push(&mut self, e: Extremum) -> Result<(), Extremum> {
        self.sinks.push_at(self.i, e)
    }
}

/// The extrema of one pixel at one angle, in increasing band order: at most
/// [`MAX_EXTREMA`], 42 bytes (a `heapless::Vec` would spend 8 bytes on its length).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExtremaList {
    items: [Extremum; MAX_EXTREMA],
    len: u8,
}

impl ExtremaList {
    /// An empty list.
    pub const fn new() -> Self {
        Self {
            items: [Extremum::ZERO; MAX_EXTREMA],
            len: 0,
        }
    }

    /// Appends `e`, or hands it back if the list is full.
    pub fn push(&mut self, e: Extremum) -> Result<(), Extremum> {
        match self.items.get_mut(usize::from(self.len)) {
            Some(slot) => {
                *slot = e;
                self.len += 1;
                Ok(())
            }
            None => Err(e),
        }
    }

    /// Empties the list.
    pub fn clear(&mut self) {
        self.len = 0;
    }
}

impl ExtremumSink for ExtremaList {
    #[inline]
    fn last_extremum(&self) -> Option<Extremum> {
        self.last().copied()
    }

    #[inline]
    fn push(&mut self, e: Extremum) -> Result<(), Extremum> {
        ExtremaList::push(self, e)
    }
}

impl core::ops::Deref for ExtremaList {
    type Target = [Extremum];
    fn deref(&self) -> &[Extremum] {
        &self.items[..usize::from(self.len)]
    }
}

/// Extrema an [`ExtremaHead`] keeps.
pub const HEAD: usize = 4;

/// The last [`HEAD`] extrema of a pixel's list at one angle (the longest wavelengths, its
/// lowest orders, on a rig whose bands rise), how many the whole list holds and how many of
/// them lie before band [`WINDOW`]: 10 bytes against an [`ExtremaList`]'s 42. It takes and
/// refuses the extrema the whole list would ([`MAX_EXTREMA`]), so the two agree on what they
/// hold and on overflow.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExtremaHead {
    items: [Extremum; HEAD],
    len: u8,
    early: u8,
}

impl ExtremaHead {
    /// An empty head.
    pub const EMPTY: Self = Self {
        items: [Extremum::ZERO; HEAD],
        len: 0,
        early: 0,
    };

    /// The head of `list`.
    pub fn of(list: &[Extremum]) -> Self {
        let mut head = Self::EMPTY;
        for &e in list {
            let _ = head.push(e);
        }
        head
    }

    /// Appends `e` (dropping the oldest kept), or hands it back if [`MAX_EXTREMA`] came
    /// already.
    pub fn push(&mut self, e: Extremum) -> Result<(), Extremum> {
        let len = usize::from(self.len);
        if len >= MAX_EXTREMA {
            return Err(e);
        }
        if len < HEAD {
            self.items[len] = e;
        } else {
            self.items.copy_within(1.., 0);
            self.items[HEAD - 1] = e;
        }
        self.len += 1;
        if e.band() < WINDOW as f32 {
            self.early += 1;
        }
        Ok(())
    }

    /// Empties the head.
    pub fn clear(&mut self) {
        *self = Self::EMPTY;
    }

    /// The extrema kept, in band order: the whole list's last.
    pub fn extrema(&self) -> &[Extremum] {
        &self.items[..usize::from(self.len).min(HEAD)]
    }

    /// How many extrema the whole list holds.
    pub fn len(&self) -> usize {
        usize::from(self.len)
    }

    /// Whether the list is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// How many of the whole list lie in bands `WINDOW..=last` (`last >= WINDOW`: the range
    /// clear of the smoothing window at either end, `WINDOW` bands before the sweep's last
    /// and never before band `WINDOW`): all but those before band
    /// `WINDOW` and those kept here past `last` (a list with more than [`HEAD`] extrema
    /// past `last`, never a clean fringe's, counts the earlier ones in).
    pub fn reliable(&self, last: f32) -> usize {
        let late = self.extrema().iter().filter(|e| e.band() > last).count();
        self.len().saturating_sub(usize::from(self.early) + late)
    }
}

impl ExtremumSink for ExtremaHead {
    #[inline]
    fn last_extremum(&self) -> Option<Extremum> {
        self.extrema().last().copied()
    }

    #[inline]
    fn push(&mut self, e: Extremum) -> Result<(), Extremum> {
        ExtremaHead::push(self, e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::Kind;

    fn list(n: usize, first: f32, step: f32) -> ExtremaList {
        let mut l = ExtremaList::new();
        for k in 0..n {
            let kind = if k % 2 == 0 { Kind::Peak } else { Kind::Valley };
            l.push(Extremum::new(first + step * k as f32, kind))
                .expect("room");
        }
        l
    }

    /// Fed the same extrema as a whole list, the head keeps its last ones, its length, and
    /// refuses the same extremum the list does.
    #[test]
    fn a_head_is_the_end_of_its_list() {
        for n in 0..=MAX_EXTREMA {
            let l = list(n, 3.0, 7.25);
            let mut head = ExtremaHead::EMPTY;
            for &e in l.iter() {
                head.push(e).expect("room");
            }
            assert_eq!(head, ExtremaHead::of(&l));
            assert_eq!(head.extrema(), &l[n.saturating_sub(HEAD)..], "{n} extrema");
            assert_eq!(head.len(), n);
            assert_eq!(head.last_extremum(), l.last().copied());
        }
        let mut full = list(MAX_EXTREMA, 3.0, 7.25);
        let mut head = ExtremaHead::of(&full);
        let e = Extremum::new(200.0, Kind::Peak);
        assert_eq!(full.push(e), Err(e));
        assert_eq!(head.push(e), Err(e));
        assert_eq!(core::mem::size_of::<ExtremaHead>(), 10);
    }

    /// The reliable count is the whole list's count of extrema in bands `WINDOW..=last`,
    /// whichever end of the band the list covers, on 100 bands and on 16 (whose range is
    /// band `WINDOW` alone).
    #[test]
    fn the_reliable_count_is_the_whole_lists() {
        let cases = [
            (0, 0.0, 1.0),
            (5, 0.5, 3.0),
            (12, 2.0, 8.5),
            (20, 1.0, 4.9),
            (20, 20.0, 4.0),
            (3, 95.0, 1.5),
            (7, 60.0, 5.5),
        ];
        let short = [(6, 4.0, 2.5), (4, 7.0, 1.0), (3, 0.5, 4.25)];
        let sweeps = [(90.0, &cases[..]), (WINDOW as f32, &short[..])];
        for (n, first, step, last) in sweeps
            .iter()
            .flat_map(|&(last, c)| c.iter().map(move |&(n, f, s)| (n, f, s, last)))
        {
            let l = list(n, first, step);
            let inside = l
                .iter()
                .filter(|e| (WINDOW as f32..=last).contains(&e.band()))
                .count();
            assert_eq!(
                ExtremaHead::of(&l).reliable(last),
                inside,
                "{n} from {first} by {step}, last {last}"
            );
        }
    }
}
