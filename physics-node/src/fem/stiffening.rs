//! State of the strain-stiffening law ([`StrainStiffening`]) in a model: the modulus factor
//! of every element, the factor its stiffness blocks were last built with, and a per-node
//! factor (volume-weighted mean of the incident elements) for the stiffness-warped contact
//! compliance.
//!
//! The elastic support stiffens by the same law: a supported node's spring stiffness is
//! k · factor(|u| / L), with u the node's displacement from rest and L the body's mean
//! thickness above its support (volume / supported area). The support lumps what holds the
//! meniscus in the joint (horn and coronary attachments, the capsule, the cartilage under it),
//! all collagenous and strain-stiffening as the tissue is, so one fitted rate describes both;
//! dividing by L makes the support's displacement a strain of the body it carries.
//!
//! The factors are taken from the committed state at the start of a step (a secant modulus
//! lagging one step), the way the element rotations of the corotational model are: the
//! implicit step then treats them as constants. Allocation-free after construction.

use nalgebra::{Matrix3, Point3};

use super::element::{qr_rotation, TetRest};
use super::material::StrainStiffening;

#[derive(Debug, Clone)]
pub(crate) struct StiffeningState {
    pub law: StrainStiffening,
    /// Modulus factor per element (1 without stiffening).
    pub elem: Vec<f64>,
    /// Factor each element's packed stiffness blocks were built with.
    pub elem_k: Vec<f64>,
    /// Volume-weighted mean factor of the elements around each node.
    pub node: Vec<f64>,
    node_volume: Vec<f64>,
    /// Largest support displacement of the committed state, m, and the support factor at it.
    pub support_displacement: f64,
    pub support_factor: f64,
}

impl StiffeningState {
    pub fn new(law: StrainStiffening, tets: &[[usize; 4]], rest: &[TetRest], nodes: usize) -> Self {
        let mut node_volume = vec![0.0; nodes];
        for (t, r) in tets.iter().zip(rest) {
            for &i in t {
                node_volume[i] += r.volume;
            }
        }
        StiffeningState {
            law,
            elem: vec![1.0; tets.len()],
            elem_k: vec![1.0; tets.len()],
            node: vec![1.0; nodes],
            node_volume,
            support_displacement: 0.0,
            support_factor: 1.0,
        }
    }

    /// Secant support stiffness of the state `x`: `support[i] = support_rest[i] ·
    /// factor(|x_i − rest_i| / length)` for every supported node (`support_rest[i] > 0`).
    /// With the linear law the support stays at rest stiffness. Allocation-free.
    pub fn update_support(
        &mut self,
        support_rest: &[f64],
        support: &mut [f64],
        x: &[Point3<f64>],
        rest: &[Point3<f64>],
        length: f64,
    ) {
        let mut largest = 0.0f64;
        for (i, (&k, s)) in support_rest.iter().zip(support.iter_mut()).enumerate() {
            if k <= 0.0 {
                continue;
            }
            let u = (x[i] - rest[i]).norm();
            largest = largest.max(u);
            *s = if self.law.is_active() && length > 0.0 {
                k * self.law.factor(u / length)
            } else {
                k
            };
        }
        self.support_displacement = largest;
        self.support_factor = if self.law.is_active() && length > 0.0 {
            self.law.factor(largest / length)
        } else {
            1.0
        };
    }

    /// Factors of the state `x` (element rotations by QR of F, falling back on `rotations`
    /// for a degenerate element). Does nothing when the law is linear.
    pub fn update(
        &mut self,
        tets: &[[usize; 4]],
        rest: &[TetRest],
        x: &[Point3<f64>],
        rotations: &[Matrix3<f64>],
    ) {
        if !self.law.is_active() {
            return;
        }
        self.node.fill(0.0);
        for (e, (t, r)) in tets.iter().zip(rest).enumerate() {
            let f = r.deformation_gradient([
                x[t[0]].coords,
                x[t[1]].coords,
                x[t[2]].coords,
                x[t[3]].coords,
            ]);
            let rot = qr_rotation(&f).unwrap_or(rotations[e]);
            let s = self
                .law
                .factor(StrainStiffening::equivalent_strain(&f, &rot));
            self.elem[e] = s;
            for &i in t {
                self.node[i] += s * r.volume;
            }
        }
        for (s, &v) in self.node.iter_mut().zip(&self.node_volume) {
            *s = if v > 0.0 { *s / v } else { 1.0 };
        }
    }

    /// Back to the unstrained factors (model reset, new law).
    pub fn reset(&mut self) {
        self.elem.fill(1.0);
        self.node.fill(1.0);
        self.support_displacement = 0.0;
        self.support_factor = 1.0;
    }
}
