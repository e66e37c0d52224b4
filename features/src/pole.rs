//! The pole: a vertical cylinder such as a tree trunk, `x_f = {x^S radius, x^2D centre}`
//! (paper section IV-H).

use serde::{Deserialize, Serialize};
use slam_core::nalgebra::{DMatrix, DVector, Vector2};
use slam_core::{
    Coincidence, CoordBlock, Coordinates, Error, Feature, Growth, Ink, Mark, Result, Shape, Sketch,
    Subspace, check_perturbation, downcast_feature,
};

/// Radius and centre, gained together.
pub const FULL: Subspace = Subspace {
    name: "full",
    rows: 3,
    description: "radius and centre: one range scan of the trunk constrains all three, so a \
                  pole is never initialized with fewer (section IV-H)",
};

/// A pole of radius `r` centred at a 2-D point (an infinite vertical cylinder).
///
/// M-space dimension 0 or 3, with B the identity (Table II).
///
/// ```
/// use slam_features::Pole;
/// use slam_core::{Feature, nalgebra::Vector2};
/// let tree = Pole::full(0.3, Vector2::new(10.0, -4.0)).unwrap();
/// assert_eq!(tree.mspace_dim(), 3);
/// assert!(Pole::new(-0.1, Vector2::new(0.0, 0.0)).is_err());
/// ```
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "PoleRepr", into = "PoleRepr")]
pub struct Pole {
    coordinates: Coordinates,
    full: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PoleRepr {
    radius: f64,
    centre: Vector2<f64>,
    dim: usize,
}

impl From<Pole> for PoleRepr {
    fn from(pole: Pole) -> Self {
        PoleRepr {
            radius: pole.radius(),
            centre: pole.centre(),
            dim: pole.mspace_dim(),
        }
    }
}

impl TryFrom<PoleRepr> for Pole {
    type Error = Error;
    fn try_from(repr: PoleRepr) -> Result<Self> {
        match repr.dim {
            0 => Pole::new(repr.radius, repr.centre),
            3 => Pole::full(repr.radius, repr.centre),
            d => Err(Error::InvalidArgument(format!(
                "a pole's M-space dimension is 0 or 3, not {d}"
            ))),
        }
    }
}

impl Pole {
    /// Smallest radius accepted, in metres.
    pub const MIN_RADIUS: f64 = 1e-4;

    /// A tentative pole (dimension 0); the radius must be at least [`Pole::MIN_RADIUS`].
    pub fn new(radius: f64, centre: Vector2<f64>) -> Result<Self> {
        Ok(Pole {
            coordinates: Self::checked(radius, centre)?,
            full: false,
        })
    }

    /// A pole with its full M-space (dimension 3).
    pub fn full(radius: f64, centre: Vector2<f64>) -> Result<Self> {
        Ok(Pole {
            full: true,
            ..Pole::new(radius, centre)?
        })
    }

    fn checked(radius: f64, centre: Vector2<f64>) -> Result<Coordinates> {
        let coordinates =
            Coordinates::new([CoordBlock::Scalar(radius), CoordBlock::Point2(centre)])?;
        if radius.is_nan() || radius < Self::MIN_RADIUS {
            return Err(Error::Degenerate(format!(
                "pole radius {radius} m is below {} m",
                Self::MIN_RADIUS
            )));
        }
        Ok(coordinates)
    }

    /// The radius.
    pub fn radius(&self) -> f64 {
        match self.coordinates.blocks()[0] {
            CoordBlock::Scalar(r) => r,
            _ => f64::NAN,
        }
    }

    /// The centre.
    pub fn centre(&self) -> Vector2<f64> {
        match self.coordinates.blocks()[1] {
            CoordBlock::Point2(c) => c,
            _ => Vector2::from_element(f64::NAN),
        }
    }
}

#[typetag::serde(name = "pole")]
impl Feature for Pole {
    fn shape(&self) -> Option<Shape> {
        Some(Shape::Pole {
            centre: self.centre(),
            radius: self.radius(),
        })
    }

    /// Another pole is this pole when their centres coincide (the radius is left out: a
    /// trunk's apparent radius varies with the height the laser cuts it at).
    fn coincidence(&self, other: &dyn Feature) -> Result<Option<Coincidence>> {
        let Some(other) = downcast_feature::<Pole>(other) else {
            return Ok(None);
        };
        let centre = |sign: f64| {
            let mut d = DMatrix::zeros(2, 3);
            d[(0, 1)] = sign;
            d[(1, 2)] = sign;
            d
        };
        Ok(Some(Coincidence {
            residual: DVector::from_column_slice((self.centre() - other.centre()).as_slice()),
            d_self: centre(1.0),
            d_other: centre(-1.0),
        }))
    }

    fn sketch(&self) -> Sketch {
        let centre = self.centre();
        Sketch::new("poles", Ink::Pole)
            .with(Mark::Circle {
                centre,
                radius: self.radius(),
                ink: Ink::Pole,
                filled: true,
            })
            .with(Mark::Ellipse {
                offset: 1,
                at: centre,
                ink: Ink::Pole,
            })
    }

    fn kind(&self) -> &'static str {
        "pole"
    }

    fn coordinates(&self) -> &Coordinates {
        &self.coordinates
    }

    /// `x_f += dx_p`: a full pole's `B~` is the identity and a tentative pole's has no
    /// columns (Table II), so the default's product `B~ dx_p` is skipped; the same numbers.
    fn apply_perturbation(&mut self, dx_p: &DVector<f64>) -> Result<()> {
        check_perturbation(self.kind(), self.mspace_dim(), dx_p)?;
        if self.full {
            let radius = self.radius() + dx_p[0];
            let centre = self.centre() + Vector2::new(dx_p[1], dx_p[2]);
            self.coordinates = Self::checked(radius, centre)?;
        }
        Ok(())
    }

    fn set_coordinates(&mut self, coordinates: Coordinates) -> Result<()> {
        let [CoordBlock::Scalar(radius), CoordBlock::Point2(centre)] = coordinates.blocks() else {
            return Err(Error::InvalidArgument(
                "a pole's coordinates are a radius and a 2-D centre".into(),
            ));
        };
        self.coordinates = Self::checked(*radius, *centre)?;
        Ok(())
    }

    fn active_subspaces(&self) -> Vec<Subspace> {
        if self.full { vec![FULL] } else { Vec::new() }
    }

    /// The rows of the active subspace, without collecting it (run for every candidate and
    /// update).
    fn mspace_dim(&self) -> usize {
        if self.full { FULL.rows } else { 0 }
    }

    fn growth_options(&self) -> Vec<Subspace> {
        if self.full { Vec::new() } else { vec![FULL] }
    }

    fn activate(&mut self, subspace: &str) -> Result<Growth> {
        if self.full || subspace != FULL.name {
            return Err(Error::Growth {
                feature: "pole",
                subspace: subspace.to_string(),
                reason: "a pole has one subspace, `full`, gained once".into(),
            });
        }
        self.full = true;
        Ok(Growth {
            subspace: FULL,
            rows: 0..3,
        })
    }

    fn projection(&self) -> Result<DMatrix<f64>> {
        Ok(if self.full {
            DMatrix::identity(3, 3)
        } else {
            DMatrix::zeros(0, 3)
        })
    }

    fn dual(&self) -> Result<DMatrix<f64>> {
        Ok(self.projection()?.transpose())
    }
}
