//! The clipped Voronoi diagram, the library's API: the cells of sites in a
//! tet mesh ([`voronoi`]) and in a periodic box, through the sites'
//! images ([`periodic`]), and what particle simulations ask of each cell
//! ([`particles`]: surface, coordination, Voronoi index), and what a
//! trajectory's frame leaves for the next ([`trajectory`]).

pub mod mesh_parts;
pub mod particles;
pub mod periodic;
pub mod periodic_parts;
mod spill;
pub mod trajectory;
pub mod voronoi;
