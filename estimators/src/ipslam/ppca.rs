//! 1-D probabilistic PCA of 2-D points (Tipping & Bishop; IPSLAM section III-A), the
//! Anderson-Darling normality test that drives G-means (section III-B), and the
//! incremental-PCA merge of two clusters (section III-E, eqs. 15-16).

use slam_core::nalgebra::{Matrix2, Vector2};

/// A list of 2-D points.
type Points = Vec<Vector2<f64>>;

/// Smallest variance of a cluster in any direction, m^2 (a cluster of collinear points would
/// otherwise have a singular density).
pub const MIN_VARIANCE: f64 = 1e-6;

/// A 1-D PPCA model of 2-D points: `z ~ N(mu, W W^T + sigma^2 I)` (eq. 10) with
/// `W = u (lambda - sigma^2)^(1/2)` (eq. 11), `u` the principal direction, `lambda` the
/// principal variance and `sigma^2` the non-principal one (eq. 13).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cluster {
    /// Centre `mu` (map frame), m.
    pub mean: Vector2<f64>,
    /// Unit principal direction `u`.
    pub direction: Vector2<f64>,
    /// Principal variance `lambda` (largest eigenvalue of the sample covariance), m^2.
    pub principal_variance: f64,
    /// `sigma^2_ML`, the non-principal variance (eq. 13), m^2.
    pub sigma2: f64,
    /// Points the cluster summarizes.
    pub count: usize,
}

impl Cluster {
    /// The closed-form maximum-likelihood fit (eqs. 11-13) of at least two points.
    pub fn fit(points: &[Vector2<f64>]) -> Option<Cluster> {
        if points.len() < 2 {
            return None;
        }
        let n = points.len() as f64;
        let mean = points.iter().sum::<Vector2<f64>>() / n;
        let mut s = Matrix2::zeros();
        for p in points {
            let d = p - mean;
            s += d * d.transpose();
        }
        s /= n; // eq. 12
        let (principal_variance, sigma2, direction) = principal(&s)?;
        Some(Cluster {
            mean,
            direction,
            principal_variance,
            sigma2,
            count: points.len(),
        })
    }

    /// `W_ML` (eq. 11, with `R = 1`).
    pub fn w(&self) -> Vector2<f64> {
        self.direction * (self.principal_variance - self.sigma2).max(0.0).sqrt()
    }

    /// `C = W W^T + sigma^2 I` (eq. 10).
    pub fn covariance(&self) -> Matrix2<f64> {
        let w = self.w();
        w * w.transpose() + Matrix2::identity() * self.sigma2.max(MIN_VARIANCE)
    }

    /// `ln N(z; mu, C)` (eq. 9).
    pub fn log_likelihood(&self, z: &Vector2<f64>) -> f64 {
        let d = z - self.mean;
        let along = d.dot(&self.direction);
        let across2 = d.norm_squared() - along * along;
        let lambda = self.principal_variance.max(MIN_VARIANCE);
        let sigma2 = self.sigma2.max(MIN_VARIANCE);
        -0.5 * (along * along / lambda
            + across2 / sigma2
            + (lambda * sigma2).ln()
            + 2.0 * (2.0 * std::f64::consts::PI).ln())
    }

    /// The cluster moved by a rigid transform `p -> R p + t` (`rotation` in radians).
    pub fn transformed(&self, rotation: f64, translation: &Vector2<f64>) -> Cluster {
        let (s, c) = rotation.sin_cos();
        let rotate = |v: &Vector2<f64>| Vector2::new(c * v.x - s * v.y, s * v.x + c * v.y);
        Cluster {
            mean: rotate(&self.mean) + translation,
            direction: rotate(&self.direction),
            ..*self
        }
    }

    /// The segment that a uniform spread of the same principal variance would cover:
    /// `mu -/+ sqrt(3 lambda) u`.
    pub fn ends(&self) -> (Vector2<f64>, Vector2<f64>) {
        let half = (3.0 * self.principal_variance).sqrt();
        (
            self.mean - self.direction * half,
            self.mean + self.direction * half,
        )
    }

    /// The sample covariance the cluster stands for.
    pub fn sample_covariance(&self) -> Matrix2<f64> {
        let u = self.direction;
        let normal = Vector2::new(-u.y, u.x);
        u * u.transpose() * self.principal_variance + normal * normal.transpose() * self.sigma2
    }
}

/// `(lambda_1, lambda_2, u_1)` of a symmetric 2 x 2 matrix, eigenvalues in descending order.
fn principal(s: &Matrix2<f64>) -> Option<(f64, f64, Vector2<f64>)> {
    let eigen = s.symmetric_eigen();
    let (i, j) = if eigen.eigenvalues[0] >= eigen.eigenvalues[1] {
        (0, 1)
    } else {
        (1, 0)
    };
    let u: Vector2<f64> = eigen.eigenvectors.column(i).into_owned();
    let norm = u.norm();
    if !(norm.is_finite() && norm > 0.0) {
        return None;
    }
    Some((
        eigen.eigenvalues[i].max(0.0),
        eigen.eigenvalues[j].max(0.0),
        u / norm,
    ))
}

/// The standard normal CDF (Abramowitz & Stegun 7.1.26 through erf, |error| < 1.5e-7).
pub fn normal_cdf(x: f64) -> f64 {
    let z = x / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * z.abs());
    let poly = t
        * (0.254_829_592
            + t * (-0.284_496_736
                + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    let erf = 1.0 - poly * (-z * z).exp();
    0.5 * (1.0 + if z >= 0.0 { erf } else { -erf })
}

/// `ln Phi(x)`, the log of the standard normal CDF, with a relative error below 1.2e-7 of
/// `Phi` everywhere, far tails included (`Phi(-40)` is about `1e-350`, below the smallest
/// double, and its log is still right): `Phi(x) = erfc(-x / sqrt 2) / 2` with the Chebyshev
/// fit of `erfc` of Numerical Recipes (`erfcc`), kept in logs. (`1 - Phi(-x)` is 0 beyond
/// about 8 sigma in doubles, which is why the upper tail is not computed that way.)
pub fn log_normal_cdf(x: f64) -> f64 {
    let z = -x / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.5 * z.abs());
    let series = -1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    // ln erfc(|z|) = ln t - z^2 + series.
    let ln_erfc_abs = t.ln() - z * z + series;
    if z >= 0.0 {
        ln_erfc_abs - std::f64::consts::LN_2
    } else {
        // erfc(z) = 2 - erfc(|z|) for z < 0.
        (-0.5 * ln_erfc_abs.exp()).ln_1p()
    }
}

/// The Anderson-Darling statistic `A^2` of `values` against a normal distribution whose mean
/// and variance are estimated from them, with Stephens' small-sample correction
/// `A*^2 = A^2 (1 + 4/n - 25/n^2)` used by G-means (Hamerly & Elkan 2003). `None` for fewer
/// than 3 values or no spread.
pub fn anderson_darling(values: &[f64]) -> Option<f64> {
    let n = values.len();
    if n < 3 {
        return None;
    }
    let nf = n as f64;
    let mean = values.iter().sum::<f64>() / nf;
    let variance = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (nf - 1.0);
    if variance.is_nan() || variance <= 0.0 {
        return None;
    }
    let sd = variance.sqrt();
    let mut sorted: Vec<f64> = values.iter().map(|v| (v - mean) / sd).collect();
    sorted.sort_by(f64::total_cmp);
    // ln Phi(x_i) + ln (1 - Phi(x_{n-1-i})), the upper tail as Phi(-x): exact in both tails.
    let sum: f64 = (0..n)
        .map(|i| {
            let lower = log_normal_cdf(sorted[i]);
            let upper = log_normal_cdf(-sorted[n - 1 - i]);
            (2.0 * i as f64 + 1.0) * (lower + upper)
        })
        .sum();
    let a2 = -nf - sum / nf;
    Some(a2 * (1.0 + 4.0 / nf - 25.0 / (nf * nf)))
}

/// Merges the points of a new cluster into an old one by incremental PCA (Weng et al.'s
/// CCIPCA as in the paper's eqs. 15-16): the principal vector `v = lambda u` is pulled
/// towards each new point, `v_m = (m-1)/m v_{m-1} + 1/m (z_m - mu)(z_m - mu)^T v_{m-1} /
/// |v_{m-1}|`, starting from the old cluster's `v_0` with `m` counting the old cluster's
/// points first. The centre is the count-weighted average of the two centres, and
/// `sigma^2` the pooled total variance minus the new principal variance.
pub fn merge(old: &Cluster, new: &Cluster, new_points: &[Vector2<f64>]) -> Cluster {
    let n_old = old.count as f64;
    let n_new = new.count as f64;
    let total = n_old + n_new;
    let mean = (old.mean * n_old + new.mean * n_new) / total;
    // v_0: the old points' scatter about the merged centre applied to the old direction
    // (eq. 15 with the old cluster's sample covariance standing for its points).
    let offset_old = old.mean - mean;
    let mut v = (old.sample_covariance() + offset_old * offset_old.transpose()) * old.direction;
    let mut m = n_old;
    for z in new_points {
        m += 1.0;
        let d = z - mean;
        let norm = v.norm();
        if norm <= 0.0 {
            break;
        }
        v = v * ((m - 1.0) / m) + d * (d.dot(&v) / norm) / m;
    }
    // Pooled sample covariance of the union (exact), for the total variance.
    let offset_new = new.mean - mean;
    let pooled = (old.sample_covariance() + offset_old * offset_old.transpose()) * (n_old / total)
        + (new.sample_covariance() + offset_new * offset_new.transpose()) * (n_new / total);
    let lambda = v.norm();
    let direction = if lambda > 0.0 {
        v / lambda
    } else {
        old.direction
    };
    let trace = pooled.trace();
    let lambda = lambda.min(trace);
    Cluster {
        mean,
        direction,
        principal_variance: lambda,
        sigma2: (trace - lambda).max(MIN_VARIANCE),
        count: old.count + new.count,
    }
}

/// Merges two clusters from their moments alone: the union's count, its centre (the
/// count-weighted average of the centres) and its sample covariance, pooled exactly from each
/// cluster's sample covariance and the offset of its centre, `S = sum_i n_i / n (S_i +
/// (mu_i - mu)(mu_i - mu)^T)`, then decomposed as in [`Cluster::fit`]. For two clusters fitted
/// to two sets of points this is the fit of the union; for a cluster made by [`merge`] it is
/// exact up to that merge's approximation of the principal direction. This is what the
/// incremental PCA of eqs. 15-16 approximates when both sides are summarized, and is used for
/// the merge of two map clusters (an addition: the paper merges map clusters with new ones
/// only). `None` when neither cluster has a point or the covariance has no eigenvector.
///
/// ```
/// use slam_core::nalgebra::Vector2;
/// use slam_estimators::ipslam::ppca::{Cluster, combine};
/// let points: Vec<Vector2<f64>> = (0..40).map(|k| Vector2::new(0.1 * k as f64, 0.01 * (k % 3) as f64)).collect();
/// let (a, b) = (Cluster::fit(&points[..25]).unwrap(), Cluster::fit(&points[25..]).unwrap());
/// let all = Cluster::fit(&points).unwrap();
/// let union = combine(&a, &b).unwrap();
/// assert_eq!(union.count, 40);
/// assert!((union.mean - all.mean).norm() < 1e-12);
/// assert!((union.principal_variance - all.principal_variance).abs() < 1e-12);
/// assert!((union.sigma2 - all.sigma2).abs() < 1e-12);
/// ```
pub fn combine(a: &Cluster, b: &Cluster) -> Option<Cluster> {
    let count = a.count.checked_add(b.count)?;
    if count == 0 {
        return None;
    }
    let (n_a, n_b, total) = (a.count as f64, b.count as f64, count as f64);
    let mean = (a.mean * n_a + b.mean * n_b) / total;
    let (offset_a, offset_b) = (a.mean - mean, b.mean - mean);
    let pooled = (a.sample_covariance() + offset_a * offset_a.transpose()) * (n_a / total)
        + (b.sample_covariance() + offset_b * offset_b.transpose()) * (n_b / total);
    let (principal_variance, sigma2, direction) = principal(&pooled)?;
    Some(Cluster {
        mean,
        direction,
        principal_variance,
        sigma2,
        count,
    })
}

/// Settings of the clustering of one scan.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GMeansParams {
    /// `A*^2` above which a cluster's residuals are not normal and it is split (the paper's
    /// 1.035).
    pub critical_value: f64,
    /// Clusters with fewer points are not split further.
    pub min_points: usize,
    /// Points whose likelihood under their best cluster is below this are outliers (the
    /// paper's 1 %).
    pub outlier_likelihood: f64,
    /// Largest number of clusters per scan.
    pub max_clusters: usize,
    /// A cluster whose non-principal deviation is above this, m, is split as well (an
    /// addition: the residuals of a scattered group can look normal, but it is no line).
    pub max_sigma: f64,
}

/// G-means with 1-D PPCA (section III-B): starting from one cluster of all points, each
/// cluster whose residuals across its principal direction fail the Anderson-Darling test is
/// split by 2-means seeded at `mu -/+ sqrt(2 lambda / pi) u`, until every cluster passes or
/// is too small; then points with likelihood below the outlier threshold under their best
/// cluster are dropped and the clusters refitted. Returns each cluster with its points.
pub fn gmeans(points: &[Vector2<f64>], params: &GMeansParams) -> Vec<(Cluster, Vec<Vector2<f64>>)> {
    let mut done: Vec<Vec<Vector2<f64>>> = Vec::new();
    let mut open: Vec<Vec<Vector2<f64>>> = vec![points.to_vec()];
    while let Some(group) = open.pop() {
        if done.len() + open.len() + 1 >= params.max_clusters || group.len() < 2 * params.min_points
        {
            done.push(group);
            continue;
        }
        let Some(cluster) = Cluster::fit(&group) else {
            done.push(group);
            continue;
        };
        if is_line(&cluster, &group, params) {
            done.push(group);
            continue;
        }
        match two_means(&group, &cluster) {
            Some((a, b)) if a.len() >= 2 && b.len() >= 2 => {
                open.push(a);
                open.push(b);
            }
            _ => done.push(group),
        }
    }
    done.retain(|g| g.len() >= params.min_points.max(2));
    let done = join_collinear(done, params);
    let fitted: Vec<Cluster> = done.iter().filter_map(|g| Cluster::fit(g)).collect();
    if fitted.is_empty() {
        return Vec::new();
    }
    // Outliers: below the likelihood threshold under the cluster that explains them best;
    // the others go to that cluster and the clusters are refitted.
    let threshold = params.outlier_likelihood.max(f64::MIN_POSITIVE).ln();
    let mut members: Vec<Vec<Vector2<f64>>> = vec![Vec::new(); fitted.len()];
    for p in points {
        let (best, value) = fitted
            .iter()
            .enumerate()
            .map(|(k, c)| (k, c.log_likelihood(p)))
            .fold((0, f64::NEG_INFINITY), |a, b| if b.1 > a.1 { b } else { a });
        if value >= threshold {
            members[best].push(*p);
        }
    }
    members.retain(|m| m.len() >= params.min_points.max(2));
    join_collinear(members, params)
        .into_iter()
        .filter_map(|m| Cluster::fit(&m).map(|c| (c, m)))
        .collect()
}

/// Whether a group is thin enough and its residuals across its principal direction pass the
/// Anderson-Darling test.
fn is_line(cluster: &Cluster, group: &[Vector2<f64>], params: &GMeansParams) -> bool {
    cluster.sigma2.sqrt() <= params.max_sigma
        && residuals_normal(cluster, group, params.critical_value)
}

/// Whether a group's residuals across its principal direction pass the Anderson-Darling
/// test (too few points pass).
fn residuals_normal(cluster: &Cluster, group: &[Vector2<f64>], critical_value: f64) -> bool {
    let normal = Vector2::new(-cluster.direction.y, cluster.direction.x);
    let residuals: Vec<f64> = group
        .iter()
        .map(|p| (p - cluster.mean).dot(&normal))
        .collect();
    anderson_darling(&residuals).is_none_or(|a| a <= critical_value)
}

/// G-means only splits; a wall cut by an early split across a corner stays in pieces. Two
/// groups whose directions are within 20 degrees and whose ends come within 0.3 m are joined
/// when the union still passes the same Anderson-Darling test (an addition to the paper).
fn join_collinear(
    mut groups: Vec<Vec<Vector2<f64>>>,
    params: &GMeansParams,
) -> Vec<Vec<Vector2<f64>>> {
    let cos_limit = 20f64.to_radians().cos();
    loop {
        let fitted: Vec<Option<Cluster>> = groups.iter().map(|g| Cluster::fit(g)).collect();
        let mut joined = None;
        'search: for i in 0..groups.len() {
            for j in i + 1..groups.len() {
                let (Some(a), Some(b)) = (&fitted[i], &fitted[j]) else {
                    continue;
                };
                if a.direction.dot(&b.direction).abs() < cos_limit {
                    continue;
                }
                let (a0, a1) = a.ends();
                let (b0, b1) = b.ends();
                let gap = [(a0 - b0), (a0 - b1), (a1 - b0), (a1 - b1)]
                    .iter()
                    .map(|d| d.norm())
                    .fold(f64::INFINITY, f64::min);
                if gap > 0.3 {
                    continue;
                }
                let union: Vec<Vector2<f64>> =
                    groups[i].iter().chain(&groups[j]).copied().collect();
                if let Some(c) = Cluster::fit(&union)
                    && is_line(&c, &union, params)
                {
                    joined = Some((i, j, union));
                    break 'search;
                }
            }
        }
        match joined {
            Some((i, j, union)) => {
                groups.swap_remove(j);
                groups[i] = union;
            }
            None => return groups,
        }
    }
}

/// 2-means of a group seeded along its principal direction (G-means' split).
fn two_means(group: &[Vector2<f64>], cluster: &Cluster) -> Option<(Points, Points)> {
    let offset =
        cluster.direction * (2.0 * cluster.principal_variance / std::f64::consts::PI).sqrt();
    let mut centres = [cluster.mean - offset, cluster.mean + offset];
    let mut assignment = vec![0usize; group.len()];
    for _ in 0..20 {
        let mut changed = false;
        for (k, p) in group.iter().enumerate() {
            let side =
                usize::from((p - centres[1]).norm_squared() < (p - centres[0]).norm_squared());
            if assignment[k] != side {
                assignment[k] = side;
                changed = true;
            }
        }
        let mut sums = [Vector2::zeros(); 2];
        let mut counts = [0usize; 2];
        for (p, &side) in group.iter().zip(&assignment) {
            sums[side] += p;
            counts[side] += 1;
        }
        if counts.contains(&0) {
            return None;
        }
        centres = [sums[0] / counts[0] as f64, sums[1] / counts[1] as f64];
        if !changed {
            break;
        }
    }
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for (p, &side) in group.iter().zip(&assignment) {
        if side == 0 { a.push(*p) } else { b.push(*p) }
    }
    Some((a, b))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal, Uniform};

    fn wall(
        from: Vector2<f64>,
        to: Vector2<f64>,
        n: usize,
        sigma: f64,
        seed: u64,
    ) -> Vec<Vector2<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, sigma).unwrap();
        let along = Uniform::new(0.0, 1.0).unwrap();
        let d = to - from;
        let normal = Vector2::new(-d.y, d.x).normalize();
        (0..n)
            .map(|_| from + d * along.sample(&mut rng) + normal * noise.sample(&mut rng))
            .collect()
    }

    #[test]
    fn ppca_fit_matches_a_direct_eigen_decomposition() {
        let points = wall(Vector2::new(1.0, 2.0), Vector2::new(4.0, 3.5), 200, 0.05, 1);
        let c = Cluster::fit(&points).unwrap();
        // Direct: the sample covariance (eq. 12) and its eigen-decomposition by nalgebra's
        // general (non-symmetric) solver on the dynamic type.
        let n = points.len() as f64;
        let mean = points.iter().sum::<Vector2<f64>>() / n;
        let mut s = slam_core::nalgebra::DMatrix::zeros(2, 2);
        for p in &points {
            let d = p - mean;
            s += slam_core::nalgebra::DMatrix::from_column_slice(2, 1, d.as_slice())
                * slam_core::nalgebra::DMatrix::from_row_slice(1, 2, d.as_slice());
        }
        s /= n;
        // Closed-form eigenvalues of a 2 x 2 symmetric matrix.
        let (a, b, d) = (s[(0, 0)], s[(0, 1)], s[(1, 1)]);
        let half_trace = 0.5 * (a + d);
        let root = (0.25 * (a - d).powi(2) + b * b).sqrt();
        let (l1, l2) = (half_trace + root, half_trace - root);
        assert!(
            (c.principal_variance - l1).abs() < 1e-12,
            "{} vs {l1}",
            c.principal_variance
        );
        assert!((c.sigma2 - l2).abs() < 1e-12, "{} vs {l2}", c.sigma2);
        let u = Vector2::new(b, l1 - a).normalize();
        assert!(c.direction.dot(&u).abs() > 1.0 - 1e-12);
        // C = W W^T + sigma^2 I has the sample covariance's eigenvalues (eq. 11).
        let cov = c.covariance();
        let e = cov.symmetric_eigen();
        let mut values = [e.eigenvalues[0], e.eigenvalues[1]];
        values.sort_by(f64::total_cmp);
        assert!((values[1] - l1).abs() < 1e-12 && (values[0] - l2).abs() < 1e-12);
        // The log-likelihood is that of N(mu, C).
        let z = Vector2::new(2.0, 3.0);
        let dz = z - mean;
        let inv = cov.try_inverse().unwrap();
        let direct = -0.5
            * (dz.dot(&(inv * dz))
                + cov.determinant().ln()
                + 2.0 * (2.0 * std::f64::consts::PI).ln());
        assert!((c.log_likelihood(&z) - direct).abs() < 1e-9);
    }

    #[test]
    fn anderson_darling_matches_known_values() {
        // Values from scipy.stats.anderson (SciPy 1.17; it reports A^2 without the
        // small-sample factor).
        let uncorrected = |values: &[f64]| {
            let n = values.len() as f64;
            anderson_darling(values).unwrap() / (1.0 + 4.0 / n - 25.0 / (n * n))
        };
        let linear: Vec<f64> = (1..=10).map(f64::from).collect();
        let known = [
            (linear, 0.141_109_247_859_793),
            (
                vec![0.1, 2.3, -1.2, 0.7, 5.0, 1.1, -0.4, 0.9],
                0.393_035_096_028_907,
            ),
            (
                (0..30).map(|i| (3.0 * f64::from(i) / 29.0).exp()).collect(),
                1.429_965_594_674_78,
            ),
        ];
        for (values, expected) in &known {
            let a = uncorrected(values);
            assert!((a - expected).abs() < 2e-5, "A^2 = {a}, scipy {expected}");
        }
        // Normal quantiles pass, a bimodal sample fails the paper's 1.035.
        let normal: Vec<f64> = (1..=50)
            .map(|i| {
                let p = (f64::from(i) - 0.5) / 50.0;
                quantile(p)
            })
            .collect();
        assert!(anderson_darling(&normal).unwrap() < 0.2);
        let bimodal: Vec<f64> = (0..60)
            .map(|i| if i % 2 == 0 { -1.0 } else { 1.0 } + 0.01 * f64::from(i % 7))
            .collect();
        assert!(anderson_darling(&bimodal).unwrap() > 1.035);
        assert!(anderson_darling(&[1.0, 1.0, 1.0]).is_none());
        // An outlier 14 sigma out: its upper tail is about 1e-44, not 0. The reference is
        // the same formula with Python's math.erfc (CPython 3.11).
        let n = 200;
        let mut far: Vec<f64> = (0..n - 1).map(|k| (k as f64 * 1.7).sin() * 0.5).collect();
        far.push(40.0);
        let a = anderson_darling(&far).unwrap();
        assert!((a - 57.4549200829983).abs() < 1e-4 * 57.45, "{a}");
        assert!((normal_cdf(1.959_964) - 0.975).abs() < 1e-6);
    }

    #[test]
    fn the_log_cdf_is_right_in_both_tails() {
        // Phi(x) from Python's math.erfc: 0.5 * erfc(-x / sqrt(2)).
        let table = [
            (-40.0, -804.6084420137538_f64),
            (-10.0, -53.23128515051247),
            (-1.0, -1.841021645009264),
            (0.0, -std::f64::consts::LN_2),
            (2.0, -0.023012909328963493),
            (9.0, -1.1285884059538422e-19),
        ];
        for (x, expected) in table {
            let got = log_normal_cdf(x);
            let error = if expected.abs() > 1e-3 {
                (got - expected).abs()
            } else {
                (got / expected - 1.0).abs()
            };
            assert!(error < 1e-6, "x {x}: {got} vs {expected}");
        }
    }

    /// The standard normal quantile by bisection of [`normal_cdf`].
    fn quantile(p: f64) -> f64 {
        let (mut lo, mut hi) = (-10.0, 10.0);
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if normal_cdf(mid) < p {
                lo = mid
            } else {
                hi = mid
            }
        }
        0.5 * (lo + hi)
    }

    #[test]
    fn ipca_merge_agrees_with_batch_pca_of_the_union() {
        let old_points = wall(Vector2::new(0.0, 0.0), Vector2::new(3.0, 0.3), 150, 0.02, 2);
        let new_points = wall(Vector2::new(2.0, 0.2), Vector2::new(5.0, 0.5), 120, 0.02, 3);
        let old = Cluster::fit(&old_points).unwrap();
        let new = Cluster::fit(&new_points).unwrap();
        let merged = merge(&old, &new, &new_points);
        let union: Vec<Vector2<f64>> = old_points.iter().chain(&new_points).copied().collect();
        let batch = Cluster::fit(&union).unwrap();
        assert_eq!(merged.count, union.len());
        assert!((merged.mean - batch.mean).norm() < 1e-9, "centres");
        let angle = merged.direction.dot(&batch.direction).abs().min(1.0).acos();
        assert!(
            angle < 2f64.to_radians(),
            "direction off by {} deg",
            angle.to_degrees()
        );
        let ratio = merged.principal_variance / batch.principal_variance;
        assert!(
            (0.85..1.15).contains(&ratio),
            "principal variance ratio {ratio}"
        );
        assert!(merged.sigma2 < 0.01, "sigma^2 {}", merged.sigma2);
    }

    #[test]
    fn gmeans_finds_the_walls_of_a_corner() {
        let mut points = wall(Vector2::new(0.0, 0.0), Vector2::new(4.0, 0.0), 120, 0.01, 4);
        points.extend(wall(
            Vector2::new(4.0, 0.0),
            Vector2::new(4.0, 3.0),
            90,
            0.01,
            5,
        ));
        points.push(Vector2::new(2.0, 2.0)); // an outlier
        let params = GMeansParams {
            critical_value: 1.035,
            min_points: 8,
            outlier_likelihood: 0.01,
            max_clusters: 20,
            max_sigma: 0.05,
        };
        let clusters = gmeans(&points, &params);
        assert!(
            (2..=4).contains(&clusters.len()),
            "{} clusters",
            clusters.len()
        );
        for (c, members) in &clusters {
            assert!(c.sigma2 < 0.01, "{c:?}");
            assert!(
                !members.contains(&Vector2::new(2.0, 2.0)),
                "the outlier was kept"
            );
        }
        let along_x = clusters.iter().any(|(c, _)| c.direction.x.abs() > 0.99);
        let along_y = clusters.iter().any(|(c, _)| c.direction.y.abs() > 0.99);
        assert!(along_x && along_y);
    }
}
