//! A worker: the rows of its strips fed band by band into the trackers and the solver's sums,
//! held in blocks of bands, each row tallied once it has seen the angle's last band.

use std::sync::Arc;

use crossbeam_channel::{Receiver, Sender};
use filmscope_core::solve::index::RatioHistogram;
use filmscope_core::solve::sweep::SolverOptions;
use filmscope_core::solve::{Shard, SweepContext};
use filmscope_core::track::unpack_samples;

use super::held::HeldBlock;
use super::msg::{Done, Start, WorkerMsg, WorkerRows};
use super::state::{BandModels, ShardState, ShardTally, Strips, Tally};
use crate::source::RowOrder;

/// Bands of the block that starts at `band` of an angle's `bands`: `band_block`, but at most
/// half of the bands left (rounded up). A block is fed once its last band has arrived, so
/// whatever is still to feed when the angle's last row arrives is latency: with the blocks
/// halving towards the end, each is fed while the next (half as many bands) arrives, and the
/// angle's last block, one band, is fed row by row as its rows arrive ([`streams_rows`]).
/// Halving down to one band, against stopping at four: `filmscope bench`'s live latency
/// drain went from 16 to 11 ms per megapixel (1 MP).
pub fn block_bands(band: usize, bands: usize, band_block: usize) -> usize {
    let left = bands.saturating_sub(band);
    band_block.min(left.div_ceil(2)).max(1)
}

/// Whether the block of `limit` bands that starts at `first` is the angle's last (of
/// `bands`): its rows are fed as its last band's rows arrive (in row order), each row of
/// every band it holds at once.
pub fn streams_rows(first: usize, limit: usize, bands: usize) -> bool {
    first + limit >= bands
}

/// A worker's strips over their states for an angle: rows routed to their strip's shard.
struct Owned<'a> {
    shards: Vec<Shard<'a>>,
    strips: Strips,
    worker: usize,
    width: usize,
}

impl<'a> Owned<'a> {
    fn new(state: &'a mut ShardState, strips: Strips, worker: usize, width: usize) -> Self {
        let shards = state.shards(strips.spans_of(worker), width);
        Self {
            shards,
            strips,
            worker,
            width,
        }
    }

    /// The shard that holds image row `row`, if this worker does.
    fn at(&mut self, row: usize) -> Option<&mut Shard<'a>> {
        let place = self.strips.place(self.worker, row)?;
        self.shards.get_mut(place)
    }

    /// The worker's first row at or after `row`.
    fn next_row(&self, row: usize) -> usize {
        self.strips.next_row(self.worker, row)
    }

    /// The worker's image rows, top to bottom.
    fn rows(&self) -> impl Iterator<Item = usize> + '_ {
        self.shards
            .iter()
            .flat_map(|s| s.first_row..s.first_row + s.rows())
    }
}

/// A worker: `block` is `[band_block, bands per angle]`; `strips` says which rows are its
/// (worker `index`'s strips); `order` is the source's. A worker behind the stream (rows
/// waiting in its queue) leaves the tally of the rows it completes to the angle's end, where
/// all cores tally them.
#[allow(clippy::too_many_arguments)]
pub(super) fn worker(
    index: usize,
    strips: Strips,
    width: usize,
    options: SolverOptions,
    block: [usize; 2],
    order: RowOrder,
    start: Receiver<Start>,
    rows: Receiver<WorkerMsg>,
    done: Sender<Done>,
) {
    let [band_block, bands] = block;
    let mut feeder = Feeder {
        index,
        strips,
        width,
        options,
        band_block,
        bands,
        order,
        held: HeldBlock::default(),
    };
    for begun in start.iter() {
        let back = feeder.angle(begun, &rows);
        if done.send(back).is_err() {
            return;
        }
    }
}

/// What a worker keeps from angle to angle: which rows are its, how it feeds them, and the
/// block of rows it holds.
struct Feeder {
    /// The worker's number ([`Strips::of_worker`]).
    index: usize,
    strips: Strips,
    width: usize,
    options: SolverOptions,
    /// Bands a block holds at most.
    band_block: usize,
    /// Bands an angle.
    bands: usize,
    order: RowOrder,
    held: HeldBlock,
}

impl Feeder {
    /// One angle: its rows from `rows` fed to the state `begun` hands over, held in blocks
    /// of bands (a line-major source's lines until the block is full), until the angle (or
    /// the calibrate stage) ends; the state and its tally handed back.
    fn angle(&mut self, begun: Start, rows: &Receiver<WorkerMsg>) -> Done {
        let Start {
            state: mut st,
            models,
            began,
            angles_left,
        } = begun;
        let (index, strips, width, options) = (self.index, self.strips, self.width, self.options);
        let (band_block, bands, order) = (self.band_block, self.bands, self.order);
        let held = &mut self.held;
        let mut owned = Owned::new(&mut st, strips, index, width);
        owned.shards.iter_mut().for_each(Shard::begin_angle);
        let shard_rows = strips.rows_of(index);
        held.size_for(band_block * shard_rows * width);
        let mut tally = RowTally::new(began, bands, &owned);
        let (mut bands_held, mut rows_of_band, mut limit) = (0, 0, band_block);
        // The block's first band, and the image row below which its held rows were fed
        // (the angle's last block: [`streams_rows`]).
        let first_row = owned.next_row(0);
        let (mut first_band, mut fed_to) = (0, first_row);
        loop {
            match rows.recv() {
                Ok(WorkerMsg::Rows(WorkerRows {
                    band,
                    first_row: row,
                    rows: n,
                    samples: values,
                })) => {
                    // Rows waiting: the worker is behind the stream.
                    let behind = !rows.is_empty();
                    if order == RowOrder::LineMajor {
                        // Lines arrive with all their bands: held until the block is full,
                        // then fed a few rows at a time with every band held, so that the
                        // rows' state stays in cache while all their bands pass (a band
                        // block would walk it once every few bands).
                        if !held.fits(values.len()) {
                            feed_rest(
                                &mut owned, options, &models, held, first_row, &mut tally, behind,
                            );
                        }
                        held.push(band, row, n, &values);
                        continue;
                    }
                    if !held.fits(values.len()) {
                        // Only rows sent twice overfill a block: feed what it holds.
                        feed_rest(
                            &mut owned, options, &models, held, fed_to, &mut tally, behind,
                        );
                        bands_held = 0;
                    }
                    if held.last_band().is_none_or(|b| b != band) {
                        if bands_held == limit {
                            feed_rest(
                                &mut owned, options, &models, held, fed_to, &mut tally, behind,
                            );
                            bands_held = 0;
                        }
                        if bands_held == 0 {
                            first_band = usize::from(band);
                            limit = block_bands(first_band, bands, band_block);
                            fed_to = first_row;
                        }
                        bands_held += 1;
                        rows_of_band = 0;
                    }
                    rows_of_band += n as usize;
                    let rows_in = row as usize..(row + n) as usize;
                    held.push(band, row, n, &values);
                    // The message's memory goes back before the block is fed.
                    drop(values);
                    if limit == 1 || (bands_held == limit && rows_of_band >= shard_rows) {
                        // A full block is fed at once, not when the next band starts (a block
                        // of one band as its rows arrive): the rows still held when the angle
                        // ends are latency.
                        feed_rest(
                            &mut owned, options, &models, held, fed_to, &mut tally, behind,
                        );
                        bands_held = 0;
                    } else if bands_held == limit
                        && rows_in.start == owned.next_row(fed_to)
                        && streams_rows(first_band, limit, bands)
                    {
                        let part = fed_to..rows_in.end;
                        feed_held(&mut owned, options, &models, held, part, &mut tally, behind);
                        fed_to = rows_in.end;
                    }
                }
                Ok(WorkerMsg::End) => break,
                // The calibrate stage stopped mid-angle: hand back what we have.
                Err(_) => break,
            }
        }
        feed_rest(&mut owned, options, &models, held, fed_to, &mut tally, true);
        // After the last angle, given back before the state is: the coordinator allocates
        // the results then.
        if angles_left <= 1 {
            held.release();
        }
        let tally = tally.finish(&owned);
        drop(owned);
        Done {
            worker: index,
            state: st,
            tally,
        }
    }
}

/// Bands before a row's last at which its extrema so far are voted ([`Shard::vote_rows`]):
/// the halving blocks of an angle's end ([`block_bands`]) span about twice the band block,
/// and an extremum is confirmed a few bands after it, so most of a row's extrema are voted
/// while the angle streams and few are left to its tally.
const VOTE_AHEAD_BANDS: u32 = 16;

/// A worker's angle-end pass 1 made row by row: a row is tallied ([`Shard::tally_rows`]) as
/// soon as it has seen the angle's last band, its state in cache and later rows still
/// streaming, so that after the angle's last row little is left to tally.
struct RowTally {
    /// The solver's context as the angle began (the pair geometry).
    solver: Arc<SweepContext>,
    /// Bands per angle.
    bands: u32,
    /// Bands fed to each image row (the worker's only).
    fed: Vec<u32>,
    tally: Box<Tally>,
    /// Votes of the extrema found before each row's last [`VOTE_AHEAD_BANDS`] bands
    /// ([`Shard::vote_rows`]): kept apart, as they count whether or not the rows' tallies do.
    early_votes: Box<RatioHistogram>,
    /// Rows left to the angle's end.
    deferred: Vec<usize>,
}

impl RowTally {
    fn new(solver: Arc<SweepContext>, bands: usize, owned: &Owned<'_>) -> Self {
        let height = owned.rows().max().map_or(0, |r| r + 1);
        Self {
            solver,
            bands: bands as u32,
            fed: vec![0; height],
            tally: Box::default(),
            early_votes: Box::default(),
            deferred: Vec::new(),
        }
    }

    /// Counts a band fed to image row `row`, votes the row's extrema so far
    /// [`VOTE_AHEAD_BANDS`] bands before its last, and tallies the row when that was its
    /// last (or defers it, if `behind`: rows wait in the worker's queue).
    fn fed(&mut self, owned: &mut Owned<'_>, row: usize, behind: bool) {
        let (Some(n), Some(shard)) = (self.fed.get_mut(row), owned.at(row)) else {
            return;
        };
        *n += 1;
        if *n + VOTE_AHEAD_BANDS == self.bands {
            shard.vote_rows(&self.solver, row..row + 1, &mut self.early_votes);
        }
        if *n == self.bands {
            if behind {
                self.deferred.push(row);
            } else {
                let Tally { votes, fit } = &mut *self.tally;
                shard.tally_rows(&self.solver, row..row + 1, votes, fit);
            }
        }
    }

    /// What was tallied of the worker's rows: when every row was fed the angle's band count
    /// (each was tallied or deferred at its last feed), the tally and the deferred rows; if
    /// any row was fed more or fewer times, no row's tally counts and every row is left (the
    /// early votes count either way).
    fn finish(self, owned: &Owned<'_>) -> ShardTally {
        let complete = owned
            .rows()
            .all(|r| self.fed.get(r).is_some_and(|&n| n == self.bands));
        let (mut tally, untallied) = if complete {
            (self.tally, self.deferred)
        } else {
            (Box::default(), owned.rows().collect())
        };
        // The early votes count either way: a row's tally votes only the extrema after them.
        tally.votes.merge(&self.early_votes);
        ShardTally { tally, untallied }
    }
}

/// Feeds the held rows from image row `from` on ([`feed_held`]) and empties `held`: a block
/// done (its rows before `from` were fed as they arrived, [`streams_rows`]).
fn feed_rest(
    owned: &mut Owned<'_>,
    options: SolverOptions,
    models: &BandModels,
    held: &mut HeldBlock,
    from: usize,
    tally: &mut RowTally,
    behind: bool,
) {
    feed_held(
        owned,
        options,
        models,
        held,
        from..usize::MAX,
        tally,
        behind,
    );
    held.clear();
}

/// Feeds the held rows of image rows `rows` to their shards a block of rows at a time, each
/// block's bands in the order they arrived (so every pixel sees its bands in order); each
/// row's last band of the angle tallies it.
fn feed_held(
    owned: &mut Owned<'_>,
    options: SolverOptions,
    models: &BandModels,
    held: &HeldBlock,
    rows: std::ops::Range<usize>,
    tally: &mut RowTally,
    behind: bool,
) {
    /// Bytes of pixel state a block of rows should keep in cache while its bands pass.
    const BLOCK_BYTES: usize = 256 * 1024;
    let width = owned.width;
    let Some(sampling) = owned.shards.first().map(Shard::sampling) else {
        return;
    };
    let bytes = filmscope_core::solve::state_bytes_per_pixel(sampling, width);
    let block_rows = (BLOCK_BYTES / (width * bytes).max(1)).max(1);
    let (Some(lo), Some(hi)) = (
        held.entries().iter().map(|h| h.image_rows().start).min(),
        held.entries().iter().map(|h| h.image_rows().end).max(),
    ) else {
        return;
    };
    let (lo, hi) = (lo.max(rows.start), hi.min(rows.end));
    let mut unpacked = vec![0.0; width];
    let mut block = lo;
    while block < hi {
        let block_end = (block + block_rows).min(hi);
        for e in held.entries() {
            let image_rows = e.image_rows();
            for r in image_rows.start.max(block)..image_rows.end.min(block_end) {
                let Some(shard) = owned.at(r) else {
                    continue;
                };
                let k = r - image_rows.start;
                unpack_samples(held.row(e, k, width), &mut unpacked, options.wide_simd);
                shard.feed_row(options, models.view(), usize::from(e.band), r, &unpacked);
                tally.fed(owned, r, behind);
            }
        }
        // The next block starts at the worker's next row (other workers' strips skipped).
        block = owned.next_row(block_end).max(block_end);
    }
}

#[cfg(test)]
mod tests {
    use super::{block_bands, streams_rows};

    /// The blocks an angle of `bands` bands is fed in, as `(first band, bands)`.
    fn blocks(bands: usize, band_block: usize) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        let mut band = 0;
        while band < bands {
            let n = block_bands(band, bands, band_block);
            out.push((band, n));
            band += n;
        }
        out
    }

    #[test]
    fn blocks_shrink_towards_an_angle_end_and_only_the_last_streams() {
        let b = blocks(161, 8);
        let mut expected: Vec<_> = (0..19).map(|k| (8 * k, 8)).collect();
        expected.extend([(152, 5), (157, 2), (159, 1), (160, 1)]);
        assert_eq!(b, expected);
        let streams: Vec<_> = b.iter().map(|&(f, n)| streams_rows(f, n, 161)).collect();
        assert_eq!(streams.iter().filter(|&&s| s).count(), 1);
        assert!(streams[streams.len() - 1]);
        // Short angles and small blocks: every band once, in order, no empty block.
        for bands in 1..40 {
            for band_block in [1, 2, 3, 4, 8, 64] {
                let b = blocks(bands, band_block);
                assert!(b.iter().all(|&(_, n)| (1..=band_block).contains(&n)));
                assert_eq!(b.iter().map(|&(_, n)| n).sum::<usize>(), bands);
            }
        }
        assert_eq!(blocks(161, 1).len(), 161);
    }
}
