//! Geometry, the engine's lowest layer: tet meshes ([`mesh`]), closed
//! triangle surfaces ([`surface`]), densities over a mesh ([`density`]),
//! point sets and their Morton order ([`points`]), the periodic box with
//! its walls ([`periodic_box`]), sums that do not depend on the order of
//! their terms ([`exact_sum`]), the integer frame the
//! kernels compare distances in ([`quantize`]), the host's site grid for
//! ball queries ([`site_grid`]), small vector helpers ([`vec3`]) and
//! per-phase times ([`timing`]). It knows no job, backend or diagram.

pub mod density;
pub mod domain;
pub mod exact_sum;
pub mod mesh;
pub mod periodic_box;
pub mod points;
pub mod quantize;
pub mod site_grid;
pub mod surface;
pub mod timing;
pub mod vec3;
