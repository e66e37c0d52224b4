//! Coordinate blocks: the three kinds of coordinates that parameterize every feature
//! (paper section IV: 3-D points, 2-D points standing for vertical lines, and scalars).

use nalgebra::{DVector, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use smallvec::SmallVec;

use crate::error::{Error, Result, ensure_finite};

/// The kind of one coordinate block (paper section IV).
///
/// ```
/// use slam_core::BlockKind;
/// assert_eq!(BlockKind::Point3.dim() + BlockKind::Point2.dim() + BlockKind::Scalar.dim(), 6);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum BlockKind {
    /// A 3-D point, `x^3D`; transforms by eq. 7.
    Point3,
    /// A 2-D point standing for an infinite vertical line, `x^2D`; transforms by eq. 8.
    Point2,
    /// A frame-independent scalar such as a pole radius, `x^S`; eq. 9 leaves it unchanged.
    Scalar,
}

impl BlockKind {
    /// Number of scalar coordinates in a block of this kind.
    pub const fn dim(self) -> usize {
        match self {
            BlockKind::Point3 => 3,
            BlockKind::Point2 => 2,
            BlockKind::Scalar => 1,
        }
    }
}

/// One coordinate block with its value, in whatever frame its owner says.
///
/// ```
/// use slam_core::{CoordBlock, nalgebra::Vector2};
/// let corner = CoordBlock::Point2(Vector2::new(1.0, 2.0));
/// assert_eq!(corner.as_slice(), &[1.0, 2.0]);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum CoordBlock {
    /// A 3-D point.
    Point3(Vector3<f64>),
    /// A 2-D point (vertical line).
    Point2(Vector2<f64>),
    /// A scalar.
    Scalar(f64),
}

impl CoordBlock {
    /// The block's kind.
    pub fn kind(&self) -> BlockKind {
        match self {
            CoordBlock::Point3(_) => BlockKind::Point3,
            CoordBlock::Point2(_) => BlockKind::Point2,
            CoordBlock::Scalar(_) => BlockKind::Scalar,
        }
    }

    /// Number of scalar coordinates.
    pub fn dim(&self) -> usize {
        self.kind().dim()
    }

    /// The values as a slice, in x, y, z order.
    pub fn as_slice(&self) -> &[f64] {
        match self {
            CoordBlock::Point3(p) => p.as_slice(),
            CoordBlock::Point2(p) => p.as_slice(),
            CoordBlock::Scalar(s) => std::slice::from_ref(s),
        }
    }

    /// The values as a mutable slice.
    pub fn as_mut_slice(&mut self) -> &mut [f64] {
        match self {
            CoordBlock::Point3(p) => p.as_mut_slice(),
            CoordBlock::Point2(p) => p.as_mut_slice(),
            CoordBlock::Scalar(s) => std::slice::from_mut(s),
        }
    }

    /// A block of `kind` made from the first `kind.dim()` values of `values`.
    pub fn from_slice(kind: BlockKind, values: &[f64]) -> Result<Self> {
        if values.len() < kind.dim() {
            return Err(Error::DimensionMismatch {
                what: format!("{kind:?} block values"),
                expected: kind.dim(),
                got: values.len(),
            });
        }
        Ok(match kind {
            BlockKind::Point3 => CoordBlock::Point3(Vector3::new(values[0], values[1], values[2])),
            BlockKind::Point2 => CoordBlock::Point2(Vector2::new(values[0], values[1])),
            BlockKind::Scalar => CoordBlock::Scalar(values[0]),
        })
    }

    /// True when every value is finite.
    #[inline]
    pub fn is_finite(&self) -> bool {
        match self {
            CoordBlock::Point3(p) => p.x.is_finite() && p.y.is_finite() && p.z.is_finite(),
            CoordBlock::Point2(p) => p.x.is_finite() && p.y.is_finite(),
            CoordBlock::Scalar(s) => s.is_finite(),
        }
    }
}

/// A feature's coordinate list `x_f`: an ordered list of blocks.
///
/// The flat vector view used by B and B~ (paper eqs. 10-12) stacks the blocks in order. Up to
/// [`INLINE_BLOCKS`] blocks are stored inline, so cloning such a list allocates nothing.
///
/// ```
/// use slam_core::{CoordBlock, Coordinates, nalgebra::{Vector2, DVector}};
/// let mut wall = Coordinates::new(vec![
///     CoordBlock::Point2(Vector2::new(0.0, 0.0)),
///     CoordBlock::Point2(Vector2::new(4.0, 0.0)),
/// ]).unwrap();
/// assert_eq!(wall.dim(), 4);
/// wall.add_vector(&DVector::from_vec(vec![0.0, 0.1, 0.0, 0.1])).unwrap();
/// assert_eq!(wall.to_vector()[1], 0.1);
/// ```
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "Vec<CoordBlock>", into = "Vec<CoordBlock>")]
pub struct Coordinates {
    blocks: SmallVec<[CoordBlock; INLINE_BLOCKS]>,
}

/// How many blocks a [`Coordinates`] holds without a heap allocation (a wall's or a pole's two).
pub const INLINE_BLOCKS: usize = 2;

impl TryFrom<Vec<CoordBlock>> for Coordinates {
    type Error = Error;
    fn try_from(blocks: Vec<CoordBlock>) -> Result<Self> {
        Coordinates::new(blocks)
    }
}

impl From<Coordinates> for Vec<CoordBlock> {
    fn from(coordinates: Coordinates) -> Self {
        coordinates.blocks.into_vec()
    }
}

impl Coordinates {
    /// A coordinate list from its blocks (a `Vec`, an array, an iterator); every value must be
    /// finite.
    ///
    /// ```
    /// use slam_core::{CoordBlock, Coordinates, nalgebra::Vector2};
    /// let pole = Coordinates::new([CoordBlock::Scalar(0.2), CoordBlock::Point2(Vector2::new(1.0, 2.0))])?;
    /// assert_eq!(pole.dim(), 3);
    /// assert!(Coordinates::new([CoordBlock::Scalar(f64::NAN)]).is_err());
    /// # Ok::<(), slam_core::Error>(())
    /// ```
    pub fn new(blocks: impl IntoIterator<Item = CoordBlock>) -> Result<Self> {
        Self::from_blocks(blocks.into_iter().collect())
    }

    /// [`Coordinates::new`] from blocks already in their storage.
    pub(crate) fn from_blocks(blocks: SmallVec<[CoordBlock; INLINE_BLOCKS]>) -> Result<Self> {
        match blocks.iter().position(|block| !block.is_finite()) {
            Some(i) => ensure_block_finite(&blocks[i], i).map(|()| Coordinates { blocks }),
            None => Ok(Coordinates { blocks }),
        }
    }

    /// The blocks in order.
    pub fn blocks(&self) -> &[CoordBlock] {
        &self.blocks
    }

    /// Block `index`, if it exists.
    pub fn block(&self, index: usize) -> Option<&CoordBlock> {
        self.blocks.get(index)
    }

    /// Number of blocks.
    pub fn num_blocks(&self) -> usize {
        self.blocks.len()
    }

    /// The kinds of the blocks, in order (the feature's layout).
    pub fn layout(&self) -> Vec<BlockKind> {
        self.blocks.iter().map(CoordBlock::kind).collect()
    }

    /// Total number of scalar coordinates, `dim(x_f)`.
    pub fn dim(&self) -> usize {
        self.blocks.iter().map(CoordBlock::dim).sum()
    }

    /// Offset of block `index` in the flat vector.
    pub fn offset(&self, index: usize) -> usize {
        self.blocks[..index.min(self.blocks.len())]
            .iter()
            .map(CoordBlock::dim)
            .sum()
    }

    /// Replaces block `index` by a block of the same kind with finite values.
    pub fn set_block(&mut self, index: usize, value: CoordBlock) -> Result<()> {
        let current = self
            .blocks
            .get(index)
            .ok_or_else(|| Error::DimensionMismatch {
                what: "coordinate block index".into(),
                expected: self.blocks.len(),
                got: index,
            })?;
        if current.kind() != value.kind() {
            return Err(Error::BlockKindMismatch {
                index,
                expected: current.kind(),
                got: value.kind(),
            });
        }
        ensure_block_finite(&value, index)?;
        self.blocks[index] = value;
        Ok(())
    }

    /// The flat vector `x_f`.
    pub fn to_vector(&self) -> DVector<f64> {
        DVector::from_iterator(
            self.dim(),
            self.blocks
                .iter()
                .flat_map(|b| b.as_slice().iter().copied()),
        )
    }

    /// A list with this layout and the values of the flat vector `x`.
    pub fn with_vector(&self, x: &DVector<f64>) -> Result<Self> {
        if x.len() != self.dim() {
            return Err(Error::DimensionMismatch {
                what: "coordinate vector".into(),
                expected: self.dim(),
                got: x.len(),
            });
        }
        let mut offset = 0;
        let mut blocks = SmallVec::<[CoordBlock; INLINE_BLOCKS]>::with_capacity(self.blocks.len());
        for block in &self.blocks {
            blocks.push(CoordBlock::from_slice(
                block.kind(),
                &x.as_slice()[offset..],
            )?);
            offset += block.dim();
        }
        Coordinates::from_blocks(blocks)
    }

    /// `x_f += dx`; leaves `self` unchanged and returns an error if the result is not finite.
    pub fn add_vector(&mut self, dx: &DVector<f64>) -> Result<()> {
        let moved = self.with_vector(&(self.to_vector() + dx))?;
        *self = moved;
        Ok(())
    }
}

/// [`ensure_finite`] for block `index`, the message formatted only on failure.
#[inline]
fn ensure_block_finite(block: &CoordBlock, index: usize) -> Result<()> {
    if block.is_finite() {
        Ok(())
    } else {
        ensure_finite(block.as_slice(), &format!("coordinate block {index}"))
    }
}
