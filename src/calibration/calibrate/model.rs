//! The least-squares model: parameters, registration and features, its whitened residuals
//! and Jacobian, and the names of its unknowns.
//!
//! **Invariant:** residuals are whitened by each feature's stated uncertainty; the model
//! never solves, it only evaluates.

use super::*;

// ---------------------------------------------------------------------------------------
// The least-squares model.

/// How the scan's frame relates to the workpiece frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Registration {
    /// Estimate a rigid registration (6 nuisance parameters) with the deviations.
    #[default]
    Estimate,
    /// The scan is in the workpiece frame.
    Workpiece,
}

/// The full model: residuals and Jacobian of features w.r.t. deviations and registration.
#[derive(Clone, Debug)]
pub struct Model<'a> {
    /// The chain at the prior (known and current values of every deviation).
    pub chain: &'a Chain,
    /// The deviations solved for.
    pub ids: &'a [DeviationId],
    /// The ISO location and squareness terms solved for, on top of the chain's values.
    pub iso_terms: &'a [IsoTerm],
    /// The tool.
    pub tool: &'a Tool,
    /// The features.
    pub features: &'a [Feature],
    /// Registration handling.
    pub registration: Registration,
}

impl Model<'_> {
    /// Number of residuals.
    pub fn rows(&self) -> usize {
        self.features.iter().map(Feature::residual_count).sum()
    }

    /// Number of unknowns: deviations, ISO terms, then 6 registration parameters if
    /// estimated (and planes are measured), then 3 per fixed point of the ball features.
    pub fn cols(&self) -> usize {
        self.params() + self.reg_cols() + 3 * self.anchor_count()
    }

    /// Number of parameters of the machine solved for: deviations, then ISO terms.
    pub fn params(&self) -> usize {
        self.ids.len() + self.iso_terms.len()
    }

    /// The parameters' names, in solve order.
    pub fn param_names(&self) -> Vec<String> {
        self.ids
            .iter()
            .map(|id| self.chain.deviation_name(*id))
            .chain(self.iso_terms.iter().map(|t| t.name.clone()))
            .collect()
    }

    /// The parameters' realistic magnitudes ([`magnitude`]), in solve order.
    pub fn param_scales(&self) -> Vec<Real> {
        self.ids
            .iter()
            .map(|id| magnitude(*id))
            .chain(
                self.iso_terms
                    .iter()
                    .map(|t| component_magnitude(t.component)),
            )
            .collect()
    }

    /// Number of registration parameters: 6 when estimated and a plane is measured.
    pub fn reg_cols(&self) -> usize {
        let planes = self.features.iter().any(|f| matches!(f, Feature::Plane(_)));
        match self.registration {
            Registration::Estimate if planes => 6,
            _ => 0,
        }
    }

    /// Number of fixed points the ball features are measured from.
    pub fn anchor_count(&self) -> usize {
        self.features
            .iter()
            .filter_map(|f| match f {
                Feature::Ball(b) => Some(b.anchor + 1),
                Feature::Plane(_) => None,
            })
            .max()
            .unwrap_or(0)
    }

    fn eval<T: Scalar>(&self, x: &[T]) -> Option<Vec<T>> {
        let (p, rest) = x.split_at(self.ids.len());
        let (t, rest) = rest.split_at(self.iso_terms.len());
        let (reg, anchors) = rest.split_at(self.reg_cols());
        let reg: [T; 6] = std::array::from_fn(|k| reg.get(k).copied().unwrap_or(T::c(0.0)));
        let params = Params {
            ids: self.ids,
            p,
            iso: self.iso_terms,
            t,
        };
        let mut out = Vec::with_capacity(self.rows());
        for f in self.features {
            out.extend(feature_residuals(
                self.chain, &params, &reg, anchors, self.tool, f,
            )?);
        }
        Some(out)
    }

    /// Whitened residuals at `x` (absolute deviation values, then registration).
    pub fn residuals(&self, x: &DVector<Real>) -> Option<DVector<Real>> {
        Some(DVector::from_vec(self.eval::<Real>(x.as_slice())?))
    }

    /// The Jacobian of the whitened residuals at `x`, by forward-mode automatic
    /// differentiation (one dual-number pass per unknown).
    pub fn jacobian(&self, x: &DVector<Real>) -> Option<DMatrix<Real>> {
        let (m, n) = (self.rows(), self.cols());
        let mut j = DMatrix::zeros(m, n);
        for k in 0..n {
            let xd: Vec<Dual> = x
                .iter()
                .enumerate()
                .map(|(i, &v)| Dual {
                    v,
                    d: if i == k { 1.0 } else { 0.0 },
                })
                .collect();
            let r = self.eval(&xd)?;
            for (i, ri) in r.iter().enumerate() {
                j[(i, k)] = ri.d;
            }
        }
        Some(j)
    }

    /// The starting point: the chain's current deviation values, ISO terms and
    /// registration zero, each fixed point at the mean of where its balls put it.
    pub fn start(&self) -> DVector<Real> {
        let mut x = DVector::zeros(self.cols());
        for (k, id) in self.ids.iter().enumerate() {
            x[k] = self.chain.deviation(*id);
        }
        let base = self.params() + self.reg_cols();
        let mut count = vec![0usize; self.anchor_count()];
        for f in self.features {
            if let Feature::Ball(b) = f {
                let p = self.chain.w_from_t(&b.q) * Point3::from(b.tool_offset) - b.measured;
                for k in 0..3 {
                    x[base + 3 * b.anchor + k] += p[k];
                }
                count[b.anchor] += 1;
            }
        }
        for (a, n) in count.iter().enumerate() {
            for k in 0..3 {
                x[base + 3 * a + k] /= (*n).max(1) as Real;
            }
        }
        x
    }

    /// Names of the nuisance unknowns after the parameters: registration, fixed points.
    pub fn nuisance_names(&self) -> Vec<String> {
        let reg = ["dx", "dy", "dz", "alpha", "beta", "gamma"];
        reg.iter()
            .take(self.reg_cols())
            .map(|r| format!("registration {r}"))
            .chain((0..self.anchor_count()).flat_map(|a| {
                ["x", "y", "z"]
                    .into_iter()
                    .map(move |c| format!("fixed point {} {c}", a + 1))
            }))
            .collect()
    }
}
