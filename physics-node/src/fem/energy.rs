//! Element and node rotations, energies and elastic forces of the committed state.

use super::*;

impl FemModel {
    /// Element rotations of the last assembly (corotational frame per tet).
    pub fn element_rotation(&self, tet: usize) -> Option<Matrix3<f64>> {
        self.elem_rot_m.get(tet).copied()
    }

    /// Recomputes per-node rotations: the average of the incident element rotations,
    /// orthonormalised (nearest rotation, warm-started). No allocation.
    pub fn update_node_rotations(&mut self) {
        self.node_rot_sum.fill(Matrix3::zeros());
        for (t, r) in self.tets.iter().zip(&self.elem_rot_m) {
            for &i in t {
                self.node_rot_sum[i] += r;
            }
        }
        for i in 0..self.x.len() {
            self.node_rot[i] = element_rotation(
                self.settings.rotation,
                &self.node_rot_sum[i],
                &mut self.node_rot_q[i],
                &self.node_rot[i],
                ROTATION_ITERATIONS,
                ROTATION_TOLERANCE,
            );
        }
    }

    /// Per-node rotations as of the last [`Self::update_node_rotations`] (which uses the
    /// element rotations of the last `free_motion`, i.e. of the committed state).
    pub fn node_rotations(&self) -> &[Matrix3<f64>] {
        &self.node_rot
    }

    /// Elastic strain energy of the committed state, J (plus support springs).
    pub fn elastic_energy(&mut self) -> f64 {
        let mut total = 0.0;
        let mut out = ElementOutput::zero();
        for (e, t) in self.tets.iter().enumerate() {
            let re = &self.rest_elems[e];
            let f = re.deformation_gradient([
                self.x[t[0]].coords,
                self.x[t[1]].coords,
                self.x[t[2]].coords,
                self.x[t[3]].coords,
            ]);
            match self.material.model {
                MaterialModel::Corotational => {
                    let mut q = self.elem_rot[e];
                    let rot = element_rotation(
                        self.settings.rotation,
                        &f,
                        &mut q,
                        &self.elem_rot_m[e],
                        ROTATION_ITERATIONS_COLD,
                        ROTATION_TOLERANCE_COLD,
                    );
                    element::corotational(re, &f, &rot, self.mu, self.lambda, false, &mut out);
                }
                MaterialModel::StableNeoHookean => {
                    element::stable_neo_hookean(
                        re,
                        &f,
                        self.mu,
                        self.lambda,
                        false,
                        false,
                        &mut out,
                    );
                }
            }
            total += out.energy;
        }
        for i in 0..self.x.len() {
            total += 0.5 * self.support[i] * (self.x[i] - self.rest[i]).norm_squared();
        }
        total
    }

    /// Kinetic energy of the committed state, J.
    pub fn kinetic_energy(&self) -> f64 {
        self.v
            .iter()
            .zip(&self.mass)
            .map(|(v, m)| 0.5 * m * v.norm_squared())
            .sum()
    }

    /// Gravitational potential energy −Σ m g·x, J.
    pub fn gravity_energy(&self) -> f64 {
        self.x
            .iter()
            .zip(&self.mass)
            .map(|(x, m)| -m * self.settings.gravity.dot(&x.coords))
            .sum()
    }

    /// Elastic nodal forces at the committed positions (N), written to `out` (len = nodes).
    pub fn elastic_forces(&mut self, out: &mut [Vector3<f64>]) -> Result<(), FemError> {
        if out.len() != self.x.len() {
            return Err(FemError::Input(
                "elastic_forces: wrong output length".into(),
            ));
        }
        self.assemble_with(
            false,
            0.0,
            false,
            true,
            ROTATION_ITERATIONS_COLD,
            ROTATION_TOLERANCE_COLD,
        );
        for i in 0..out.len() {
            out[i] = self.force[i] - (self.x[i] - self.rest[i]) * self.support[i];
        }
        Ok(())
    }
}
