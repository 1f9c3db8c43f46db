//! The simulation seen through [`FluidView`], the read access the scenes' observables use.

use super::FluidView;
use crate::physics::particle_cells::BodyForce;
use crate::physics::simulation::Simulation;
use blockflow_kernels::rigid::Body;
use blockflow_kernels::Real;

impl<T: Real> FluidView for Simulation<T> {
    fn visit(&self, f: &mut dyn FnMut([usize; 3], f64, [f64; 3])) {
        self.for_each_fluid(f)
    }
    fn steps_taken(&self) -> u64 {
        self.step
    }
    fn bodies(&self) -> Vec<Body> {
        self.particles.as_ref().map_or_else(Vec::new, |p| p.bodies(self.step))
    }
    fn hydro_forces(&self) -> Vec<BodyForce> {
        crate::physics::coupling::tasks::total_forces(&self.blocks)
    }
}
