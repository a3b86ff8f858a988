//! Memory layouts of the types that cross the CPU/GPU boundary, described
//! from the Rust types themselves (`core::mem::offset_of!`, `size_of`), so
//! that a description cannot drift from the code. The exported manifest
//! (see `docs/EMBEDDING.md`) is written from these descriptions.
//!
//! Host-only: not compiled for SPIR-V.

use crate::abi::{
    ClipParams, DomainParams, GridBuildParams, GridParams, KnnParams, LloydParams, RefineParams, SplitPoint,
};
use core::mem::{align_of, offset_of, size_of};

/// What a type is made of.
#[derive(Clone, Copy, Debug)]
pub enum Kind {
    /// A scalar (`u32`, `i32`, `u64`, `i64`, `f32`).
    Scalar,
    /// A fixed-size array of `len` elements of `element`.
    Array {
        /// The element's layout.
        element: fn() -> TypeLayout,
        /// Number of elements.
        len: usize,
    },
    /// A `#[repr(C)]` struct: its fields in memory order.
    Struct(&'static [Field]),
}

/// The layout of one type: name, size, alignment and parts.
#[derive(Clone, Copy, Debug)]
pub struct TypeLayout {
    /// The type's name (`u32`, `[f32; 4]`, `GridParams`).
    pub name: &'static str,
    /// `size_of` the type, in bytes.
    pub size: usize,
    /// `align_of` the type, in bytes.
    pub align: usize,
    /// Scalar, array or struct.
    pub kind: Kind,
}

/// One field of a struct.
#[derive(Clone, Copy, Debug)]
pub struct Field {
    /// The field's name.
    pub name: &'static str,
    /// Its offset in the struct, in bytes (`offset_of!`).
    pub offset: usize,
    /// Its type's layout.
    pub ty: fn() -> TypeLayout,
}

/// A type whose memory layout can be described.
pub trait Layout {
    /// The type's layout.
    fn describe() -> TypeLayout;
}

macro_rules! scalar {
    ($($t:ty),*) => {$(
        impl Layout for $t {
            fn describe() -> TypeLayout {
                TypeLayout { name: stringify!($t), size: size_of::<$t>(), align: align_of::<$t>(), kind: Kind::Scalar }
            }
        }
    )*};
}
scalar!(u32, i32, u64, i64, f32);

macro_rules! array {
    ($($t:ty, $n:literal);*) => {$(
        impl Layout for [$t; $n] {
            fn describe() -> TypeLayout {
                TypeLayout {
                    name: concat!("[", stringify!($t), "; ", stringify!($n), "]"),
                    size: size_of::<[$t; $n]>(),
                    align: align_of::<[$t; $n]>(),
                    kind: Kind::Array { element: <$t as Layout>::describe, len: $n },
                }
            }
        }
    )*};
}
array!(u32, 2; u32, 3; u32, 4; f32, 4);

/// Implements [`Layout`] for a `#[repr(C)]` struct from the list of all its
/// fields and their types; the compiler checks that the list is complete
/// (an exhaustive pattern) and that each type is right.
macro_rules! structure {
    ($s:ident { $($f:ident: $t:ty),* $(,)? }) => {
        impl Layout for $s {
            fn describe() -> TypeLayout {
                const FIELDS: &[Field] =
                    &[$(Field { name: stringify!($f), offset: offset_of!($s, $f), ty: <$t as Layout>::describe }),*];
                #[allow(dead_code)]
                fn complete(v: $s) {
                    let $s { $($f),* } = v;
                    $(let _: $t = $f;)*
                }
                TypeLayout { name: stringify!($s), size: size_of::<$s>(), align: align_of::<$s>(), kind: Kind::Struct(FIELDS) }
            }
        }
    };
}

structure!(SplitPoint { hi: [f32; 4], lo: [f32; 4] });
structure!(GridParams {
    dim_x: u32,
    dim_y: u32,
    dim_z: u32,
    cell_size: u32,
    n_sites: u32,
    n_cells: u32,
    _pad: [u32; 2]
});
structure!(GridBuildParams { grid: GridParams, n_blocks: u32, _pad: [u32; 3] });
structure!(KnnParams {
    grid: GridParams,
    n_queries: u32,
    k: u32,
    exclude_self: u32,
    query_base: u32,
    in_order: u32,
    local_lists: u32,
    _pad: [u32; 2]
});
structure!(ClipParams {
    n_sites: u32,
    n_tets: u32,
    k_site: u32,
    k_tet: u32,
    fixed_scale: f32,
    box_lo_x: f32,
    box_lo_y: f32,
    box_lo_z: f32,
    box_hi_x: f32,
    box_hi_y: f32,
    box_hi_z: f32,
    tet_base: u32,
    nbr_base: u32,
    nbr_end: u32,
    own_lo: u32,
    own_hi: u32,
    faces_base: u32,
    area_scale: f32,
    walk_margin: f32,
    capacity: u32,
    weight_range: f32,
    face_masses: u32,
    list_bits: u32,
    faces_first: u32
});
structure!(DomainParams {
    lo_x: f32,
    lo_y: f32,
    lo_z: f32,
    voxel_len: f32,
    dim_x: u32,
    dim_y: u32,
    dim_z: u32,
    n_nodes: u32,
    margin: f32,
    whole: u32,
    _pad: [u32; 2]
});
structure!(RefineParams {
    clip: ClipParams,
    grid: GridParams,
    grid_lo_x: f32,
    grid_lo_y: f32,
    grid_lo_z: f32,
    cell_len: f32,
    held_lo_x: u32,
    held_lo_y: u32,
    held_lo_z: u32,
    held_dim_x: u32,
    held_dim_y: u32,
    held_dim_z: u32,
    _pad: [u32; 2]
});
structure!(LloydParams {
    n_sites: u32,
    fixed_scale: f32,
    iteration: u32,
    quant_scale: f32,
    quant_origin_x: f32,
    quant_origin_y: f32,
    quant_origin_z: f32,
    _pad: u32,
});

/// A visitor of scalars: `(path, array index, offset, the scalar's layout)`.
pub type ScalarVisitor<'a> = dyn FnMut(&[&str], Option<usize>, usize, &TypeLayout) + 'a;

impl TypeLayout {
    /// Calls `f(path, offset, layout)` for every scalar inside this type,
    /// in memory order; `path` names it from this type (`grid.dim_x`,
    /// `_pad[1]`), `offset` is from this type's start.
    pub fn for_each_scalar(&self, f: &mut ScalarVisitor) {
        self.walk(&mut [""; 8], 0, None, 0, f);
    }

    fn walk(
        &self,
        path: &mut [&'static str; 8],
        depth: usize,
        index: Option<usize>,
        offset: usize,
        f: &mut ScalarVisitor,
    ) {
        match self.kind {
            Kind::Scalar => f(&path[..depth], index, offset, self),
            Kind::Array { element, len } => {
                let e = element();
                for i in 0..len {
                    e.walk(path, depth, Some(i), offset + i * e.size, f);
                }
            }
            Kind::Struct(fields) => {
                for field in fields {
                    path[depth] = field.name;
                    (field.ty)().walk(path, depth + 1, None, offset + field.offset, f);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(t: TypeLayout) {
        // No implicit padding: the scalars tile the type exactly.
        let mut end = 0;
        t.for_each_scalar(&mut |path, _, offset, s| {
            assert_eq!(offset, end, "{}: a gap before {path:?}", t.name);
            assert_eq!(offset % s.align, 0, "{}: {path:?} is misaligned", t.name);
            end = offset + s.size;
        });
        assert_eq!(end, t.size, "{}: padding at the end", t.name);
        assert_eq!(t.size % 16, 0, "{}: not a 16-byte multiple", t.name);
    }

    #[test]
    fn abi_structs_have_no_implicit_padding() {
        for t in [
            GridParams::describe(),
            GridBuildParams::describe(),
            KnnParams::describe(),
            ClipParams::describe(),
            RefineParams::describe(),
            DomainParams::describe(),
            LloydParams::describe(),
            SplitPoint::describe(),
        ] {
            check(t);
        }
    }

    #[test]
    fn nested_offsets() {
        let mut found = None;
        RefineParams::describe().for_each_scalar(&mut |path, _, offset, _| {
            if path == ["grid", "n_cells"] {
                found = Some(offset);
            }
        });
        assert_eq!(found, Some(offset_of!(RefineParams, grid) + offset_of!(GridParams, n_cells)));
    }
}
