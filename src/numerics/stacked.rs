//! The stacked, band-passed design matrix and target of one fit.
//!
//! The rows are cut into blocks of at most [`BLOCK_ROWS`] that never cross
//! a fold (calibration window), and each block is stored column-major with
//! its row count rounded up to [`LANES`] (zero rows below the data), so the
//! solver reads every block as a matrix without copying it. Column `p`
//! after the `p` design columns is the target; columns past it are zero.
//!
//! The filter fills the store first as panels of [`LANES`] columns written
//! row by row ([`StackedBuilder`]): a zero-phase pass runs eight columns per
//! vector instruction in place. [`StackedBuilder::finish`] then transposes
//! each block's panels in place, which turns them into the block's columns.

use std::ops::Range;
use std::sync::Mutex;

use faer::{Mat, MatRef};
use rayon::prelude::*;

use crate::numerics::filter::LANES;
use crate::numerics::linalg::{gram, multiply};

/// Rows per block of the passes over the rows.
pub const BLOCK_ROWS: usize = 2048;

/// Above this size (glibc's largest mmap threshold) an allocation is
/// always fresh pages from the operating system.
const FRESH_PAGES_BYTES: usize = 32 << 20;

/// One block of rows.
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    /// Fold (calibration window) the rows belong to.
    pub fold: usize,
    /// Rows of the stacked matrix.
    pub rows: Range<usize>,
    /// Start of the block's storage.
    offset: usize,
    /// Stored rows: `rows.len()` rounded up to [`LANES`].
    stride: usize,
}

/// The block layout shared by the builder and the finished store.
#[derive(Debug, Clone, PartialEq)]
struct Layout {
    columns: usize,
    panels: usize,
    rows: usize,
    folds: Vec<Range<usize>>,
    blocks: Vec<Block>,
}

impl Layout {
    fn new(fold_lengths: &[usize], columns: usize) -> (Self, usize) {
        let panels = (columns + 1).div_ceil(LANES);
        let mut folds = Vec::with_capacity(fold_lengths.len());
        let mut blocks = Vec::new();
        let (mut row, mut offset) = (0, 0);
        for (fold, &length) in fold_lengths.iter().enumerate() {
            folds.push(row..row + length);
            for start in (row..row + length).step_by(BLOCK_ROWS) {
                let rows = start..(start + BLOCK_ROWS).min(row + length);
                let stride = rows.len().next_multiple_of(LANES);
                blocks.push(Block {
                    fold,
                    rows,
                    offset,
                    stride,
                });
                offset += stride * panels * LANES;
            }
            row += length;
        }
        let layout = Layout {
            columns,
            panels,
            rows: row,
            folds,
            blocks,
        };
        (layout, offset)
    }

    /// The block holding `row`.
    fn block_of(&self, row: usize) -> &Block {
        let index = self.blocks.partition_point(|b| b.rows.end <= row);
        &self.blocks[index]
    }
}

/// The store while the filter fills it: each block's panels row by row.
#[derive(Debug)]
pub struct StackedBuilder {
    data: Vec<[f64; LANES]>,
    layout: Layout,
}

impl StackedBuilder {
    /// A store for `columns` design columns and the target, for folds of
    /// the given lengths, stacked in order, taken from `stores` when it
    /// holds one large enough. The padding rows are zero; the caller writes
    /// every other row of every panel (through [`Self::segments_mut`]),
    /// because the store may be a recycled one.
    pub fn new(fold_lengths: &[usize], columns: usize, stores: &StorePool) -> Self {
        let (layout, size) = Layout::new(fold_lengths, columns);
        let rows = size / LANES;
        if let Some(mut data) = stores.take(rows) {
            data.truncate(rows);
            data.resize(rows, [0.0; LANES]);
            for block in &layout.blocks {
                for panel in 0..layout.panels {
                    let start = block.offset / LANES + panel * block.stride;
                    data[start + block.rows.len()..start + block.stride].fill([0.0; LANES]);
                }
            }
            return StackedBuilder { data, layout };
        }
        // A large store comes straight from the operating system as zero
        // pages, first touched by the filter's threads. A smaller one may be
        // memory the allocator reuses, where a zeroed allocation is a
        // single-threaded memset, so both threads zero it.
        let data = if size * std::mem::size_of::<f64>() > FRESH_PAGES_BYTES {
            vec![[0.0; LANES]; rows]
        } else {
            let mut data = Vec::with_capacity(rows);
            data.par_extend(rayon::iter::repeat_n([0.0; LANES], rows));
            data
        };
        StackedBuilder { data, layout }
    }

    /// Number of panels of [`LANES`] columns.
    pub fn panel_count(&self) -> usize {
        self.layout.panels
    }

    /// For every panel and every range of `ranges` (disjoint, increasing
    /// stacked rows), the panel rows of that range as consecutive segments
    /// (one per block it spans): `[panel][range][segment]`.
    pub fn segments_mut(&mut self, ranges: &[Range<usize>]) -> Vec<Vec<Vec<&mut [[f64; LANES]]>>> {
        let layout = &self.layout;
        let panels = layout.panels;
        let mut out: Vec<Vec<Vec<&mut [[f64; LANES]]>>> = (0..panels)
            .map(|_| ranges.iter().map(|_| Vec::new()).collect())
            .collect();
        for (block, storage) in per_block(&layout.blocks, &mut self.data, |b| b.stride * panels) {
            for (panel, region) in storage.chunks_exact_mut(block.stride).enumerate() {
                let mut rows = &mut region[..block.rows.len()];
                let mut at = block.rows.start;
                for (index, range) in ranges.iter().enumerate() {
                    let start = range.start.max(at);
                    let end = range.end.min(block.rows.end);
                    if start >= end {
                        continue;
                    }
                    let (_, from) = std::mem::take(&mut rows).split_at_mut(start - at);
                    let (piece, after) = from.split_at_mut(end - start);
                    out[panel][index].push(piece);
                    rows = after;
                    at = end;
                }
            }
        }
        out
    }

    /// The finished store: every block's panels transposed in place into
    /// the block's columns, and the block's Gram matrix taken while it is
    /// still in cache, blocks in parallel.
    pub fn finish(mut self) -> Stacked {
        let (panels, columns) = (self.layout.panels, self.layout.columns);
        let grams = per_block(&self.layout.blocks, &mut self.data, |b| b.stride * panels)
            .into_par_iter()
            .map_init(Vec::new, |scratch, (block, storage)| {
                for region in storage.chunks_exact_mut(block.stride) {
                    scratch.clear();
                    scratch.extend_from_slice(region);
                    transpose_panel(scratch, region.as_flattened_mut(), block.stride);
                }
                let width = columns + 1;
                let view = MatRef::from_column_major_slice(
                    &storage.as_flattened()[..block.stride * width],
                    block.stride,
                    width,
                );
                gram(view.get(.., ..columns))
            })
            .collect();
        Stacked {
            data: self.data,
            layout: self.layout,
            grams,
        }
    }
}

/// Stores of finished fits, kept for the next [`StackedBuilder`]: repeated
/// fits (a diagnosis makes hundreds) then neither fault in fresh pages nor
/// zero memory. The caller owns the pool and hands it to every fit that may
/// share it, across threads; [`StorePool::recycle`] returns a finished
/// store to it, and dropping the pool frees them all. It keeps at most
/// `SPARE_STORES`, the largest.
#[derive(Debug, Default)]
pub struct StorePool {
    spares: Mutex<Vec<Vec<[f64; LANES]>>>,
}

/// Spare stores a pool keeps: one per thread of this machine's fits.
const SPARE_STORES: usize = 2;

impl StorePool {
    /// An empty pool.
    pub fn new() -> Self {
        StorePool::default()
    }

    /// The smallest spare store that holds `rows` rows.
    fn take(&self, rows: usize) -> Option<Vec<[f64; LANES]>> {
        let mut spares = self.spares.lock().ok()?;
        let best = (spares.iter().enumerate())
            .filter(|(_, spare)| spare.capacity() >= rows)
            .min_by_key(|(_, spare)| spare.capacity())
            .map(|(index, _)| index)?;
        Some(spares.swap_remove(best))
    }

    /// Keeps the store of a finished fit for the next builder, in place of
    /// the smallest spare when the pool is full.
    pub fn recycle(&self, stacked: Stacked) {
        let data = stacked.data;
        let Ok(mut spares) = self.spares.lock() else { return };
        if spares.len() < SPARE_STORES {
            spares.push(data);
        } else if let Some(smallest) = spares.iter_mut().min_by_key(|spare| spare.capacity()) {
            if smallest.capacity() < data.capacity() {
                *smallest = data;
            }
        }
    }
}

/// `data` cut into consecutive pieces, `size(block)` items for each block.
fn per_block<'b, 'd, T>(
    blocks: &'b [Block],
    data: &'d mut [T],
    size: impl Fn(&Block) -> usize,
) -> Vec<(&'b Block, &'d mut [T])> {
    let mut pieces = Vec::with_capacity(blocks.len());
    let mut rest = data;
    for block in blocks {
        let (piece, tail) = rest.split_at_mut(size(block));
        pieces.push((block, piece));
        rest = tail;
    }
    pieces
}

/// `rows` rows of [`LANES`] values into [`LANES`] columns of `rows` values.
fn transpose_panel(from: &[[f64; LANES]], to: &mut [f64], rows: usize) {
    // Tile by tile of LANES rows (`rows` is a whole number of tiles), so a
    // tile's reads and each column's writes are one cache line each.
    for (t, tile) in from.chunks_exact(LANES).enumerate() {
        for lane in 0..LANES {
            let column: [f64; LANES] = std::array::from_fn(|r| tile[r][lane]);
            to[lane * rows + t * LANES..][..LANES].copy_from_slice(&column);
        }
    }
}

/// Design columns and target in column-major row blocks.
#[derive(Debug, Clone, PartialEq)]
pub struct Stacked {
    data: Vec<[f64; LANES]>,
    layout: Layout,
    /// $A_b^\top A_b$ of every block's design columns.
    grams: Vec<Mat<f64>>,
}

impl Stacked {
    /// From design columns and a target of equal lengths, with the folds
    /// given as consecutive lengths (their sum the number of rows).
    pub fn from_columns(columns: &[Vec<f64>], target: &[f64], fold_lengths: &[usize]) -> Self {
        let (layout, size) = Layout::new(fold_lengths, columns.len());
        let mut data = vec![[0.0; LANES]; size / LANES];
        let flat = data.as_flattened_mut();
        for block in &layout.blocks {
            for (j, values) in columns.iter().map(Vec::as_slice).chain([target]).enumerate() {
                let start = block.offset + j * block.stride;
                flat[start..start + block.rows.len()].copy_from_slice(&values[block.rows.clone()]);
            }
        }
        let mut stacked = Stacked {
            data,
            layout,
            grams: Vec::new(),
        };
        let p = stacked.columns();
        stacked.grams = (stacked.blocks().par_iter())
            .map(|block| gram(stacked.block_view(block).get(.., ..p)))
            .collect();
        stacked
    }

    /// The stack of some of this one's folds, in the order given: bit for
    /// bit what band-passing and stacking those folds' windows alone gives,
    /// since a fold's blocks, their storage and their Gram matrices depend
    /// on its own rows only. Nothing is filtered again.
    pub fn folds_subset(&self, folds: &[usize], stores: &StorePool) -> Stacked {
        let lengths: Vec<usize> = folds.iter().map(|&f| self.layout.folds[f].len()).collect();
        let (layout, size) = Layout::new(&lengths, self.layout.columns);
        let rows = size / LANES;
        let mut data = match stores.take(rows) {
            Some(mut data) => {
                data.truncate(rows);
                data.resize(rows, [0.0; LANES]);
                data
            }
            None => vec![[0.0; LANES]; rows],
        };
        let mut grams = Vec::with_capacity(layout.blocks.len());
        let sources =
            (folds.iter()).flat_map(|&f| (self.layout.blocks.iter().enumerate()).filter(move |(_, b)| b.fold == f));
        let (from, to) = (self.data.as_flattened(), data.as_flattened_mut());
        // The blocks of a fold tile its storage in the same strides here and
        // there, padding included, so each block is one copy.
        for (target, (index, source)) in layout.blocks.iter().zip(sources) {
            let length = source.stride * layout.panels * LANES;
            to[target.offset..target.offset + length].copy_from_slice(&from[source.offset..source.offset + length]);
            grams.push(self.grams[index].clone());
        }
        Stacked { data, layout, grams }
    }

    /// Takes the target of `other`, a stack of the same folds with no
    /// design columns, in place of this one's: the design columns and their
    /// Gram matrices stay. False, with nothing changed, when the folds
    /// differ.
    pub fn take_target(&mut self, other: &Stacked) -> bool {
        if other.layout.folds != self.layout.folds || other.layout.columns != 0 {
            return false;
        }
        let p = self.layout.columns;
        let flat = self.data.as_flattened_mut();
        for (block, source) in self.layout.blocks.iter().zip(&other.layout.blocks) {
            let start = block.offset + p * block.stride;
            flat[start..start + block.stride].copy_from_slice(other.block_target(source));
        }
        true
    }

    /// $A^\top A$ of the design columns: the blocks' Gram matrices summed in
    /// block order.
    pub fn gram(&self) -> Mat<f64> {
        let p = self.columns();
        let mut total = Mat::zeros(p, p);
        for block in &self.grams {
            total += block;
        }
        total
    }

    /// Number of rows.
    pub fn rows(&self) -> usize {
        self.layout.rows
    }

    /// Number of design columns (the target not counted).
    pub fn columns(&self) -> usize {
        self.layout.columns
    }

    /// The folds, consecutive ranges of rows.
    pub fn folds(&self) -> &[Range<usize>] {
        &self.layout.folds
    }

    /// The row blocks, in order.
    pub fn blocks(&self) -> &[Block] {
        &self.layout.blocks
    }

    /// A block's design columns and target (the last column) with its zero
    /// padding rows: `stride × (columns + 1)`.
    pub fn block_view(&self, block: &Block) -> MatRef<'_, f64> {
        let width = self.layout.columns + 1;
        let storage = &self.data.as_flattened()[block.offset..block.offset + block.stride * width];
        MatRef::from_column_major_slice(storage, block.stride, width)
    }

    /// A block's target with its zero padding rows.
    pub fn block_target(&self, block: &Block) -> &[f64] {
        let start = block.offset + self.layout.columns * block.stride;
        &self.data.as_flattened()[start..start + block.stride]
    }

    /// Value of design column `column` (or the target, `column == columns`) at `row`.
    pub fn value(&self, row: usize, column: usize) -> f64 {
        let block = self.layout.block_of(row);
        self.data.as_flattened()[block.offset + column * block.stride + (row - block.rows.start)]
    }

    /// One design column, or the target for `column == columns`.
    pub fn column(&self, column: usize) -> Vec<f64> {
        self.column_range(column, 0..self.rows())
    }

    /// Rows `range` of one column.
    pub fn column_range(&self, column: usize, range: Range<usize>) -> Vec<f64> {
        let mut out = Vec::with_capacity(range.len());
        for block in &self.layout.blocks {
            let start = range.start.max(block.rows.start);
            let end = range.end.min(block.rows.end);
            if start < end {
                let base = block.offset + column * block.stride - block.rows.start;
                out.extend_from_slice(&self.data.as_flattened()[base + start..base + end]);
            }
        }
        out
    }

    /// The target.
    pub fn target(&self) -> Vec<f64> {
        self.column(self.columns())
    }

    /// The target block by block, in row order, without copying it.
    pub fn target_pieces(&self) -> impl Iterator<Item = &[f64]> {
        (self.layout.blocks.iter()).map(|block| &self.block_target(block)[..block.rows.len()])
    }

    /// $A\beta$ for the design columns, blocks in parallel, each row's sum
    /// in column order (the same whatever the thread count).
    pub fn predict(&self, coefficients: &[f64]) -> Vec<f64> {
        let p = self.columns();
        let beta = MatRef::from_column_major_slice(&coefficients[..p], p, 1);
        let mut fitted = vec![0.0; self.rows()];
        per_block(&self.layout.blocks, &mut fitted, |b| b.rows.len())
            .into_par_iter()
            .for_each(|(block, out)| {
                let rows = out.len();
                let view = self.block_view(block).get(..rows, ..p);
                multiply(faer::MatMut::from_column_major_slice_mut(out, rows, 1), view, beta);
            });
        fitted
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn example(rows: usize) -> (Vec<Vec<f64>>, Vec<f64>) {
        let columns: Vec<Vec<f64>> = (0..11)
            .map(|j| (0..rows).map(|i| (i * (j + 1)) as f64 * 0.25 - j as f64).collect())
            .collect();
        let target = (0..rows).map(|i| i as f64 * 3.0).collect();
        (columns, target)
    }

    #[test]
    fn columns_come_back_as_given() {
        let (columns, target) = example(5000);
        let stacked = Stacked::from_columns(&columns, &target, &[1000, 4000]);
        assert_eq!((stacked.rows(), stacked.columns()), (5000, 11));
        // Blocks never cross a fold: 1000 | 2048 + 1952.
        let ranges: Vec<Range<usize>> = stacked.blocks().iter().map(|b| b.rows.clone()).collect();
        assert_eq!(ranges, vec![0..1000, 1000..3048, 3048..5000]);
        for (j, column) in columns.iter().enumerate() {
            assert_eq!(&stacked.column(j), column);
        }
        assert_eq!(stacked.target(), target);
        assert_eq!(stacked.column_range(3, 990..1010), columns[3][990..1010].to_vec());
        assert_eq!(stacked.value(3047, 9), columns[9][3047]);
        let view = stacked.block_view(&stacked.blocks()[2]);
        assert_eq!((view.nrows(), view.ncols()), (1952, 12));
        assert_eq!(view[(5, 11)], target[3053]);
        assert_eq!(stacked.block_target(&stacked.blocks()[2])[5], target[3053]);
    }

    #[test]
    fn target_pieces_are_the_target_in_order() {
        let (columns, target) = example(5000);
        let stacked = Stacked::from_columns(&columns, &target, &[1000, 13, 3987]);
        let pieces: Vec<f64> = stacked.target_pieces().flatten().copied().collect();
        assert_eq!(pieces, target);
        assert_eq!(stacked.target(), target);
    }

    #[test]
    fn padding_rows_are_zero() {
        let (columns, target) = example(13);
        let stacked = Stacked::from_columns(&columns, &target, &[13]);
        let view = stacked.block_view(&stacked.blocks()[0]);
        assert_eq!(view.nrows(), 16);
        assert!((13..16).all(|i| (0..12).all(|j| view[(i, j)] == 0.0)));
    }

    /// Filling panels row by row and finishing gives the same store as
    /// building it from columns.
    #[test]
    fn built_panels_equal_the_columns() {
        let (columns, target) = example(4500);
        let folds = [300, 4200];
        let mut builder = StackedBuilder::new(&folds, columns.len(), &StorePool::new());
        let ranges = [0..300, 300..2000, 2000..4500];
        let mut segments = builder.segments_mut(&ranges);
        for (panel, per_range) in segments.iter_mut().enumerate() {
            for (range, pieces) in ranges.iter().zip(per_range.iter_mut()) {
                let mut row = range.start;
                for piece in pieces.iter_mut() {
                    for lanes in piece.iter_mut() {
                        for (lane, value) in lanes.iter_mut().enumerate() {
                            let j = panel * LANES + lane;
                            *value = match j {
                                j if j < columns.len() => columns[j][row],
                                j if j == columns.len() => target[row],
                                _ => 0.0,
                            };
                        }
                        row += 1;
                    }
                }
                assert_eq!(row, range.end);
            }
        }
        assert_eq!(builder.finish(), Stacked::from_columns(&columns, &target, &folds));
    }

    /// A recycled store holds the last fit's values; once the builder has
    /// written every row, none of them is left, padding included.
    #[test]
    fn recycled_store_leaves_nothing_behind() {
        let (columns, target) = example(700);
        let folds = [200, 500];
        for _ in 0..3 {
            // A recycled store of NaN, just larger than the one built next,
            // becomes the best-fitting spare.
            let stores = StorePool::new();
            let stale: Vec<Vec<f64>> = vec![vec![f64::NAN; 713]; columns.len()];
            stores.recycle(Stacked::from_columns(&stale, &[f64::NAN; 713], &[713]));
            let mut builder = StackedBuilder::new(&folds, columns.len(), &stores);
            let whole = 0..700;
            for (panel, pieces) in builder
                .segments_mut(std::slice::from_ref(&whole))
                .iter_mut()
                .enumerate()
            {
                for (row, lanes) in pieces[0].iter_mut().flat_map(|piece| piece.iter_mut()).enumerate() {
                    *lanes = std::array::from_fn(|lane| match panel * LANES + lane {
                        j if j < columns.len() => columns[j][row],
                        j if j == columns.len() => target[row],
                        _ => 0.0,
                    });
                }
            }
            assert_eq!(builder.finish(), Stacked::from_columns(&columns, &target, &folds));
        }
    }

    #[test]
    fn gram_is_the_design_columns_products() {
        let (columns, target) = example(5000);
        let stacked = Stacked::from_columns(&columns, &target, &[1000, 4000]);
        let gram = stacked.gram();
        for (i, a) in columns.iter().enumerate() {
            for (j, b) in columns.iter().enumerate() {
                let expected: f64 = a.iter().zip(b).map(|(x, y)| x * y).sum();
                assert!(
                    (gram[(i, j)] - expected).abs() <= 1e-12 * expected.abs().max(1.0),
                    "{i},{j}"
                );
            }
        }
    }

    #[test]
    fn predict_is_the_weighted_sum_of_the_design_columns() {
        let (columns, target) = example(3000);
        let stacked = Stacked::from_columns(&columns, &target, &[3000]);
        let beta: Vec<f64> = (0..11).map(|j| 0.5 - j as f64 * 0.125).collect();
        let fitted = stacked.predict(&beta);
        for (i, &f) in fitted.iter().enumerate() {
            let expected: f64 = columns.iter().zip(&beta).map(|(c, b)| c[i] * b).sum();
            assert!((f - expected).abs() <= 1e-12 * expected.abs().max(1.0), "row {i}");
        }
    }
}
