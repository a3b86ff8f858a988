//! The exported SPIR-V modules against their manifest: every fact the
//! manifest states about an entry point is read back from the module
//! itself (rspirv) — entry point, workgroup size, each storage buffer's
//! set, binding, element layout and stride, read-only decoration, the
//! push-constant block's members, capabilities and extensions — and each
//! module passes `spirv-val`.

use rspirv::dr::{Instruction, Module, Operand};
use rspirv::spirv::{Decoration, ExecutionMode, ExecutionModel, Op, StorageClass};
use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};

/// A scalar at an offset: `(offset, "u32")`.
type Leaves = Vec<(u64, String)>;

/// Decorations by target id and member: `(decoration, extra operands)`.
type Decorations = HashMap<(u32, Option<u32>), Vec<(Decoration, Vec<Operand>)>>;

struct Reflected {
    module: Module,
    defs: HashMap<u32, Instruction>,
    decorations: Decorations,
}

impl Reflected {
    fn new(bytes: &[u8]) -> Self {
        let module = rspirv::dr::load_bytes(bytes).expect("a parsable SPIR-V module");
        let defs = module.types_global_values.iter().filter_map(|i| i.result_id.map(|id| (id, i.clone()))).collect();
        let mut decorations = Decorations::new();
        for a in &module.annotations {
            match a.class.opcode {
                Op::Decorate => decorations
                    .entry((a.operands[0].unwrap_id_ref(), None))
                    .or_default()
                    .push((a.operands[1].unwrap_decoration(), a.operands[2..].to_vec())),
                Op::MemberDecorate => decorations
                    .entry((a.operands[0].unwrap_id_ref(), Some(a.operands[1].unwrap_literal_bit32())))
                    .or_default()
                    .push((a.operands[2].unwrap_decoration(), a.operands[3..].to_vec())),
                _ => {}
            }
        }
        Self { module, defs, decorations }
    }

    fn decoration(&self, id: u32, member: Option<u32>, d: Decoration) -> Option<&[Operand]> {
        self.decorations.get(&(id, member))?.iter().find(|(x, _)| *x == d).map(|(_, ops)| &ops[..])
    }

    fn literal(&self, id: u32, member: Option<u32>, d: Decoration) -> Option<u64> {
        Some(self.decoration(id, member, d)?[0].unwrap_literal_bit32() as u64)
    }

    fn def(&self, id: u32) -> &Instruction {
        self.defs.get(&id).unwrap_or_else(|| panic!("no definition of %{id}"))
    }

    fn scalar_size(&self, ty: u32) -> u64 {
        let t = self.def(ty);
        match t.class.opcode {
            Op::TypeInt | Op::TypeFloat => t.operands[0].unwrap_literal_bit32() as u64 / 8,
            op => panic!("%{ty} is a {op:?}, not a scalar"),
        }
    }

    /// Every scalar inside type `ty` at offset `base`, as the module lays
    /// it out (member Offset and ArrayStride decorations).
    fn leaves(&self, ty: u32, base: u64, out: &mut Leaves) {
        let t = self.def(ty);
        match t.class.opcode {
            Op::TypeInt => {
                let (w, signed) = (t.operands[0].unwrap_literal_bit32(), t.operands[1].unwrap_literal_bit32());
                out.push((base, format!("{}{w}", if signed == 1 { "i" } else { "u" })));
            }
            Op::TypeFloat => out.push((base, format!("f{}", t.operands[0].unwrap_literal_bit32()))),
            Op::TypeVector => {
                let (c, n) = (t.operands[0].unwrap_id_ref(), t.operands[1].unwrap_literal_bit32() as u64);
                for i in 0..n {
                    self.leaves(c, base + i * self.scalar_size(c), out);
                }
            }
            Op::TypeArray => {
                let (e, len) = (t.operands[0].unwrap_id_ref(), t.operands[1].unwrap_id_ref());
                let n = self.def(len).operands[0].unwrap_literal_bit32() as u64;
                let stride = self.literal(ty, None, Decoration::ArrayStride).expect("an array has an ArrayStride");
                for i in 0..n {
                    self.leaves(e, base + i * stride, out);
                }
            }
            Op::TypeStruct => {
                for (m, member) in t.operands.iter().enumerate() {
                    let offset = self.literal(ty, Some(m as u32), Decoration::Offset).expect("a member has an Offset");
                    self.leaves(member.unwrap_id_ref(), base + offset, out);
                }
            }
            op => panic!("unexpected type {op:?} in a buffer"),
        }
    }

    /// The struct type a variable of `class` points to.
    fn block_of(&self, var: &Instruction) -> u32 {
        let ptr = self.def(var.result_type.expect("a variable has a type"));
        assert_eq!(ptr.class.opcode, Op::TypePointer);
        let block = ptr.operands[1].unwrap_id_ref();
        assert_eq!(self.def(block).class.opcode, Op::TypeStruct, "an interface block is a struct");
        block
    }

    fn variables(&self, class: StorageClass) -> Vec<&Instruction> {
        self.module
            .types_global_values
            .iter()
            .filter(|i| i.class.opcode == Op::Variable && i.operands[0].unwrap_storage_class() == class)
            .collect()
    }
}

/// Every scalar of a manifest layout (`type`, `fields`, `element`/`len`).
fn manifest_leaves(layout: &Value, base: u64, out: &mut Leaves) {
    if let Some(fields) = layout["fields"].as_array() {
        for f in fields {
            manifest_leaves(f, base + f["offset"].as_u64().unwrap(), out);
        }
    } else if let Some(len) = layout["len"].as_u64() {
        let e = &layout["element"];
        for i in 0..len {
            manifest_leaves(e, base + i * e["size"].as_u64().unwrap(), out);
        }
    } else {
        out.push((base, layout["type"].as_str().unwrap().to_string()));
    }
}

fn export_dir() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("cvd-spirv-manifest-{}", std::process::id()));
    cvd::spirv::export(&dir).expect("export the modules");
    dir
}

fn names(insts: &[Instruction], f: impl Fn(&Instruction) -> String) -> BTreeSet<String> {
    insts.iter().map(f).collect()
}

fn check_module(dir: &Path, m: &Value, workgroup_size: u64) {
    let name = m["name"].as_str().unwrap();
    let bytes = std::fs::read(dir.join(m["file"].as_str().unwrap())).expect("the module's file");
    let r = Reflected::new(&bytes);

    // One entry point, GLCompute, with the manifest's name and workgroup size.
    assert_eq!(r.module.entry_points.len(), 1, "{name}: one entry point per module");
    let ep = &r.module.entry_points[0];
    assert_eq!(ep.operands[0], Operand::ExecutionModel(ExecutionModel::GLCompute), "{name}");
    assert_eq!(ep.operands[2].unwrap_literal_string(), m["entry_point"].as_str().unwrap(), "{name}");
    let func = ep.operands[1].unwrap_id_ref();
    let size = r
        .module
        .execution_modes
        .iter()
        .find(|e| {
            e.operands[0].unwrap_id_ref() == func && e.operands[1].unwrap_execution_mode() == ExecutionMode::LocalSize
        })
        .map(|e| e.operands[2..5].iter().map(|o| o.unwrap_literal_bit32() as u64).collect::<Vec<_>>())
        .unwrap_or_else(|| panic!("{name}: no LocalSize"));
    let want: Vec<u64> = m["workgroup_size"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
    assert_eq!(size, want, "{name}: workgroup size");
    assert_eq!(size[0], workgroup_size, "{name}: WORKGROUP_SIZE");

    // Storage buffers: exactly the manifest's, each a block holding a
    // runtime array whose stride and scalars are the element's.
    let mut spirv_bindings = BTreeMap::new();
    for var in r.variables(StorageClass::StorageBuffer) {
        let id = var.result_id.unwrap();
        let set = r.literal(id, None, Decoration::DescriptorSet).unwrap_or_else(|| panic!("{name}: no set"));
        let binding = r.literal(id, None, Decoration::Binding).unwrap_or_else(|| panic!("{name}: no binding"));
        assert!(spirv_bindings.insert((set, binding), var).is_none(), "{name}: binding {binding} twice");
    }
    let bindings = m["bindings"].as_array().unwrap();
    let listed: BTreeSet<(u64, u64)> =
        bindings.iter().map(|b| (b["set"].as_u64().unwrap(), b["binding"].as_u64().unwrap())).collect();
    for key in spirv_bindings.keys() {
        assert!(listed.contains(key), "{name}: SPIR-V binding {key:?} missing from the manifest");
    }
    for b in bindings {
        let key = (b["set"].as_u64().unwrap(), b["binding"].as_u64().unwrap());
        let bname = b["name"].as_str().unwrap();
        assert_eq!(b["descriptor_type"], "STORAGE_BUFFER");
        let var =
            spirv_bindings.get(&key).unwrap_or_else(|| panic!("{name}.{bname}: binding {key:?} not in the SPIR-V"));
        let block = r.block_of(var);
        assert!(r.decoration(block, None, Decoration::Block).is_some(), "{name}.{bname}: not a Block");
        let members = &r.def(block).operands;
        assert_eq!(members.len(), 1, "{name}.{bname}: one member");
        let array = members[0].unwrap_id_ref();
        assert_eq!(r.def(array).class.opcode, Op::TypeRuntimeArray, "{name}.{bname}: a runtime array");
        let stride = r.literal(array, None, Decoration::ArrayStride).expect("a runtime array has a stride");
        assert_eq!(stride, b["array_stride"].as_u64().unwrap(), "{name}.{bname}: stride");
        assert_eq!(stride, b["element"]["size"].as_u64().unwrap(), "{name}.{bname}: element size");
        let (mut got, mut want) = (Vec::new(), Vec::new());
        r.leaves(r.def(array).operands[0].unwrap_id_ref(), 0, &mut got);
        manifest_leaves(&b["element"], 0, &mut want);
        assert_eq!(got, want, "{name}.{bname}: element layout");
        let read_only = r.decoration(var.result_id.unwrap(), None, Decoration::NonWritable).is_some()
            || r.decoration(block, Some(0), Decoration::NonWritable).is_some();
        assert_eq!(read_only, b["access"] == "read_only", "{name}.{bname}: NonWritable vs {}", b["access"]);
    }

    // The push-constant block: its members' offsets and scalar types, and
    // its size within the manifest's.
    let push = &m["push_constants"];
    let vars = r.variables(StorageClass::PushConstant);
    assert_eq!(vars.len(), 1, "{name}: one push-constant block");
    let block = r.block_of(vars[0]);
    let mut got = Vec::new();
    r.leaves(block, 0, &mut got);
    let mut want = Vec::new();
    manifest_leaves(&push["layout"], 0, &mut want);
    assert_eq!(got, want, "{name}: push-constant layout");
    let flat: Leaves = push["scalars"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| (s["offset"].as_u64().unwrap(), s["type"].as_str().unwrap().to_string()))
        .collect();
    assert_eq!(flat, want, "{name}: flattened push constants");
    let end = got.iter().map(|(o, t)| o + t[1..].parse::<u64>().unwrap() / 8).max().unwrap_or(0);
    assert_eq!(end, push["size"].as_u64().unwrap(), "{name}: push-constant size");

    // Capabilities and extensions, as the module declares them.
    let caps = names(&r.module.capabilities, |i| format!("{:?}", i.operands[0].unwrap_capability()));
    let listed: BTreeSet<String> =
        m["capabilities"].as_array().unwrap().iter().map(|c| c.as_str().unwrap().to_string()).collect();
    assert_eq!(caps, listed, "{name}: capabilities");
    let exts = names(&r.module.extensions, |i| i.operands[0].unwrap_literal_string().to_string());
    let listed: BTreeSet<String> =
        m["extensions"].as_array().unwrap().iter().map(|c| c.as_str().unwrap().to_string()).collect();
    assert_eq!(exts, listed, "{name}: extensions");
    assert!(!caps.contains("Float64"), "{name}: no module needs Float64");

    // And the module is valid as it is exported.
    let out = std::process::Command::new("spirv-val")
        .args(["--target-env", "vulkan1.2"])
        .arg(dir.join(m["file"].as_str().unwrap()))
        .output()
        .expect("spirv-val (Debian's spirv-tools, which the build needs too)");
    assert!(out.status.success(), "{name}: spirv-val: {}", String::from_utf8_lossy(&out.stderr));
}

#[test]
fn manifest_matches_the_spirv() {
    let dir = export_dir();
    let manifest: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("manifest.json")).unwrap()).expect("valid JSON");
    assert_eq!(manifest["abi_version"].as_u64(), Some(cvd_kernels::interface::ABI_VERSION as u64));
    let wg = manifest["constants"]["WORKGROUP_SIZE"].as_u64().unwrap();
    let modules = manifest["modules"].as_array().unwrap();
    assert_eq!(modules.len(), cvd_kernels::interface::ENTRY_POINTS.len());
    assert_eq!(modules.len(), cvd::spirv::MODULES.len(), "one module per entry point");
    // Every entry point the library dispatches is exported (the Vulkan
    // backend runs the exported modules).
    let dispatched: BTreeSet<String> =
        cvd_kernels::interface::ENTRY_POINTS.iter().map(|e| e.spirv_name.to_string()).collect();
    let exported: BTreeSet<String> = modules.iter().map(|m| m["entry_point"].as_str().unwrap().to_string()).collect();
    assert_eq!(dispatched, exported);
    for m in modules {
        check_module(&dir, m, wg);
    }
    // The grid and scan kernels load on devices without 64-bit integers.
    for name in ["grid_count", "scan_blocks", "scan_totals", "scan_offsets", "grid_scatter", "grid_sort"] {
        let m = modules.iter().find(|m| m["name"] == name).unwrap();
        assert!(!m["capabilities"].as_array().unwrap().iter().any(|c| c == "Int64"), "{name} needs no Int64");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
