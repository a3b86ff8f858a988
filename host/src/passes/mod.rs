//! Host passes over a backend's output, run on the CPU runtime
//! ([`crate::exec`]) with the kernels' own bodies: the second pass that
//! finishes what the kernels could not ([`second_pass`]), each site's
//! faces and neighbours ([`faces`]), the pieces of each cell inside each
//! tet ([`pieces`]) and each cell as one polyhedron ([`polyhedra`]).

pub mod faces;
pub mod pieces;
pub mod polyhedra;
pub mod second_pass;
