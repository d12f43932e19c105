//! What the sparse pattern is built from: unknowns in blocks of three
//! scalars, and the entries that couple them.

/// The most blocks one entry may couple (the element kernels' node limit).
pub const MAX_ENTRY_BLOCKS: usize = cleave_kernels::corotation::MAX_NODES;

/// Unknown blocks and how they couple, in groups of entries.
///
/// Every entry (an element of a nodal family; an element's own unknowns or
/// the two elements across a face for a discontinuous one) couples a list
/// of unknown blocks, each with every other: the global matrix has a 3x3
/// block at every pair. Entries have stable ids (mesh element ids for the
/// nodal families) that survive a topology change, and sit at a `(group,
/// index)` that may move; the pattern refreshes where an id sits through
/// [`Couplings::locate`].
pub trait Couplings: Sync {
    /// Number of groups.
    fn groups(&self) -> usize;
    /// Number of entries of `group`.
    fn entries(&self, group: usize) -> usize;
    /// The unknown blocks entry `entry` of `group` couples, in its local
    /// order (the order its matrix columns are given in); at most
    /// [`MAX_ENTRY_BLOCKS`].
    fn blocks(&self, group: usize, entry: usize) -> &[u32];
    /// The stable id of entry `entry` of `group`.
    fn id(&self, group: usize, entry: usize) -> u32;
    /// Where the entry with stable id `id` sits now: `(group, index)`.
    fn locate(&self, id: u32) -> (u32, u32);
}
