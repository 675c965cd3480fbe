//! A thin, safe wrapper over MuJoCo 3.3.7: a compiled [`Model`] shared read-only (`Arc`) by any
//! number of [`Simulation`]s, each with its own `mjData` and its own copy of the few model arrays
//! that tasks write at run time.
//!
//! This module and [`crate::render`] (the offscreen renderer over the same library) are the only
//! ones of the project with `unsafe`. The library is loaded once per process
//! (path baked in by `build.rs`, overridable with `TERL_MUJOCO_LIB`). Every slice we hand out is
//! sized from the model's own counts, so the safe API cannot read past MuJoCo's arrays.
//!
//! Sharing. MuJoCo's simulation functions (`mj_step`, `mj_forward`, `mj_kinematics`,
//! `mj_resetData`, ...) take `const mjModel*`, so one model can serve many `mjData` on many
//! threads ("Multi-threading" in the MuJoCo programming guide). Meta-World writes three model
//! arrays at reset (`model.body_pos`, `model.site_pos`; `eq_data` by `reset_mocap_welds`), which
//! in Python is harmless because every env compiles its own model. Here each `Simulation` sees the
//! model through its own copy of the `mjModel` struct (a few KB) whose `body_pos`, `site_pos` and
//! `eq_data` pointers are redirected to per-simulation arrays; every other pointer reads the
//! shared buffer, which nothing writes after [`Model::from_xml`] returns.
#![allow(unsafe_code)]

use std::ffi::{c_char, CStr, CString};
use std::path::{Path, PathBuf};
use std::ptr::NonNull;
use std::sync::{Arc, OnceLock};

use crate::error::{Result, SimError};
use crate::ffi;

/// The MuJoCo version this crate's bindings were generated for (`mj_version()`).
pub const MUJOCO_VERSION: i32 = 337;

struct Loaded {
    api: ffi::MuJoCoLib,
    // Kept open so the global handler variables stay valid for the life of the process.
    _vars: libloading::Library,
}

// SAFETY: after loading, `Loaded` is never mutated: it holds the library handle and immutable
// function pointers (plus pointers to MuJoCo's constant string tables), all valid process-wide.
unsafe impl Send for Loaded {}
// SAFETY: see above; shared references only read immutable function pointers.
unsafe impl Sync for Loaded {}

static LIBRARY: OnceLock<std::result::Result<Loaded, String>> = OnceLock::new();

/// Path of the MuJoCo shared library this process uses.
pub fn library_path() -> PathBuf {
    std::env::var_os("TERL_MUJOCO_LIB")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("TERL_MUJOCO_LIB_DEFAULT")))
}

extern "C" fn log_mujoco_warning(msg: *const c_char) {
    if msg.is_null() {
        return;
    }
    // SAFETY: MuJoCo passes a NUL-terminated message valid for the duration of the call.
    let text = unsafe { CStr::from_ptr(msg) }.to_string_lossy();
    tracing::warn!(target: "mujoco", "{text}");
}

/// Handler of MuJoCo's fatal errors. When the stack part of the `mjData` arena runs out,
/// `mj_stackAlloc` calls `mju_error`, which must not return. The default handler prints and calls `exit(1)`; this one
/// says what to change first, then exits the same way.
extern "C" fn report_mujoco_error(msg: *const c_char) {
    let text = if msg.is_null() {
        "(no message)".into()
    } else {
        // SAFETY: MuJoCo passes a NUL-terminated message valid for the duration of the call.
        unsafe { CStr::from_ptr(msg) }.to_string_lossy()
    };
    let hint = if text.contains("stack") || text.contains("memory") {
        " The mjData arena is too small for this scene: raise TERL_MUJOCO_ARENA_BYTES \
         (see terl_sim::metaworld::arena_bytes)."
    } else {
        ""
    };
    tracing::error!(target: "mujoco", "fatal MuJoCo error: {text}.{hint}");
    eprintln!("fatal MuJoCo error: {text}.{hint}");
    std::process::exit(1);
}

fn load() -> std::result::Result<Loaded, String> {
    let path = library_path();
    if !path.exists() {
        return Err(SimError::LibraryMissing { path }.to_string());
    }
    // SAFETY: loading libmujoco runs no initialisers with preconditions; all symbols are
    // resolved eagerly (`dynamic_link_require_all`) so a wrong library fails here, not later.
    let api = unsafe { ffi::MuJoCoLib::new(&path) }.map_err(|e| {
        SimError::LibraryLoad {
            path: path.clone(),
            reason: e.to_string(),
        }
        .to_string()
    })?;
    // SAFETY: mj_version has no preconditions.
    let found = unsafe { api.mj_version() };
    if found != MUJOCO_VERSION {
        return Err(SimError::Version {
            found,
            expected: MUJOCO_VERSION,
        }
        .to_string());
    }
    // SAFETY: same library file as above; dlopen returns the already-loaded handle.
    let vars = unsafe { libloading::Library::new(&path) }.map_err(|e| e.to_string())?;
    type Handler = Option<unsafe extern "C" fn(*const c_char)>;
    // SAFETY: `mju_user_warning` is a global `void (*)(const char*)` in libmujoco; we write it
    // once, before any simulation exists, with a handler that only logs.
    unsafe {
        let sym: libloading::Symbol<*mut Handler> =
            vars.get(b"mju_user_warning\0").map_err(|e| e.to_string())?;
        **sym = Some(log_mujoco_warning);
    }
    // SAFETY: `mju_user_error` is a global `void (*)(const char*)` in libmujoco, written once
    // before any simulation exists; the handler never returns (it exits the process), as
    // mju_error requires. The XML compiler installs its own thread-local handler, so compile
    // errors still come back through mj_loadXML's error buffer.
    unsafe {
        let sym: libloading::Symbol<*mut Handler> =
            vars.get(b"mju_user_error\0").map_err(|e| e.to_string())?;
        **sym = Some(report_mujoco_error);
    }
    Ok(Loaded { api, _vars: vars })
}

fn api() -> Result<&'static ffi::MuJoCoLib> {
    match LIBRARY.get_or_init(load) {
        Ok(l) => Ok(&l.api),
        Err(msg) => Err(SimError::LibraryLoad {
            path: library_path(),
            reason: msg.clone(),
        }),
    }
}

/// Object kinds that can be looked up by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ObjKind {
    /// A body (`mjOBJ_BODY`).
    Body,
    /// A joint (`mjOBJ_JOINT`).
    Joint,
    /// A geom (`mjOBJ_GEOM`).
    Geom,
    /// A site (`mjOBJ_SITE`).
    Site,
}

impl ObjKind {
    fn raw(self) -> i32 {
        (match self {
            ObjKind::Body => ffi::mjOBJ_BODY,
            ObjKind::Joint => ffi::mjOBJ_JOINT,
            ObjKind::Geom => ffi::mjOBJ_GEOM,
            ObjKind::Site => ffi::mjOBJ_SITE,
        }) as i32
    }
    fn label(self) -> &'static str {
        match self {
            ObjKind::Body => "body",
            ObjKind::Joint => "joint",
            ObjKind::Geom => "geom",
            ObjKind::Site => "site",
        }
    }
}

/// One active contact: the two geoms and the row of its normal force in `efc_force`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Contact {
    /// Id of the first geom in contact (`mjContact.geom[0]`).
    pub geom1: i32,
    /// Id of the second geom in contact (`mjContact.geom[1]`).
    pub geom2: i32,
    /// Address in the constraint arrays, `-1` if the contact is not included.
    pub efc_address: i32,
}

/// Warning kinds that mean the simulation state is no longer trustworthy.
pub const UNSTABLE_WARNINGS: [usize; 3] = [
    ffi::mjWARN_BADQPOS as usize,
    ffi::mjWARN_BADQVEL as usize,
    ffi::mjWARN_BADQACC as usize,
];

/// Warning kinds that mean the `mjData` arena ran out (contacts or constraints were dropped).
pub const ARENA_WARNINGS: [usize; 2] = [
    ffi::mjWARN_CONTACTFULL as usize,
    ffi::mjWARN_CNSTRFULL as usize,
];

/// A compiled MuJoCo model, read-only once built; share it with `Arc` between simulations (and
/// threads). Dropping the last reference frees it (`mj_deleteModel`).
pub struct Model {
    api: &'static ffi::MuJoCoLib,
    ptr: NonNull<ffi::mjModel>,
    released_bytes: usize,
    /// The rendering arrays' pointers were nulled by [`Model::release_render_data`].
    render_data_released: bool,
}

// SAFETY: after construction nothing writes through `ptr` (all `&mut` accessors of Simulation
// write per-simulation arrays, see `Simulation::new`); MuJoCo only reads a `const mjModel*`, which
// its documentation allows from several threads at once.
unsafe impl Send for Model {}
// SAFETY: see above: shared references only lead to reads.
unsafe impl Sync for Model {}

impl std::fmt::Debug for Model {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Model")
            .field("nbuffer", &self.m().nbuffer)
            .field("narena", &self.m().narena)
            .field("released_bytes", &self.released_bytes)
            .finish()
    }
}

impl Drop for Model {
    fn drop(&mut self) {
        // SAFETY: the pointer came from mj_loadXML and is freed once; no Simulation outlives the
        // Arc<Model> it holds.
        unsafe { self.api.mj_deleteModel(self.ptr.as_ptr()) }
    }
}

/// Bytes of one OS page (4 KiB on x86-64 Linux; only used to align `madvise` ranges).
const PAGE: usize = 4096;

impl Model {
    /// Compiles an MJCF file: `mj_parseXML`, `mj_compile`, `mj_deleteSpec`, which is what
    /// `mj_loadXML` does except that `mj_loadXML` keeps the parsed spec as MuJoCo's global
    /// "last model" (for `mj_saveLastXML`), ~48 MB of decoded meshes for a Meta-World scene.
    pub fn from_xml(path: &Path) -> Result<Self> {
        let api = api()?;
        let fail = |message: String| SimError::ModelLoad {
            path: path.to_path_buf(),
            message,
        };
        let cpath = CString::new(path.to_string_lossy().as_bytes())
            .map_err(|_| fail("path contains a NUL byte".into()))?;
        let mut err = [0 as c_char; 1024];
        // SAFETY: cpath is NUL-terminated; err is a writable buffer of the size we pass.
        let spec = unsafe {
            api.mj_parseXML(
                cpath.as_ptr(),
                std::ptr::null(),
                err.as_mut_ptr(),
                err.len() as i32,
            )
        };
        if spec.is_null() {
            // SAFETY: MuJoCo NUL-terminates the error buffer.
            let message = unsafe { CStr::from_ptr(err.as_ptr()) };
            return Err(fail(message.to_string_lossy().into_owned()));
        }
        // SAFETY: spec is a valid parsed spec; compile reads the files it names from disk.
        let model = unsafe { api.mj_compile(spec, std::ptr::null()) };
        let compile_error = NonNull::new(model).is_none().then(|| {
            // SAFETY: mjs_getError returns a NUL-terminated string owned by the spec, read
            // before the spec is deleted.
            unsafe { CStr::from_ptr(api.mjs_getError(spec)) }
                .to_string_lossy()
                .into_owned()
        });
        // SAFETY: the spec came from mj_parseXML and is deleted once; the model owns copies of
        // everything it needs.
        unsafe { api.mj_deleteSpec(spec) };
        let ptr = match (NonNull::new(model), compile_error) {
            (Some(ptr), _) => ptr,
            (None, message) => return Err(fail(message.unwrap_or_default())),
        };
        // MuJoCo keeps decoded mesh and texture files in a process-wide asset cache (capacity
        // 500 MB by default; ~90 MB after one Meta-World scene) to speed up later compiles of
        // the same files. A process here compiles each scene once, so the cache is emptied: a
        // later compile decodes the files again, to the same values. The compiler's freed
        // temporaries stay resident in glibc's heap unless trimmed; give them back too.
        // SAFETY: mj_getCache returns MuJoCo's global cache; clearing it only drops cached
        // assets (compiles copy what they use into their model).
        unsafe { api.mj_clearCache(api.mj_getCache()) };
        #[cfg(all(target_os = "linux", target_env = "gnu"))]
        // SAFETY: malloc_trim only returns free heap pages to the OS; no preconditions.
        unsafe {
            libc::malloc_trim(0);
        }
        Ok(Self {
            api,
            ptr,
            released_bytes: 0,
            render_data_released: false,
        })
    }

    fn m(&self) -> &ffi::mjModel {
        // SAFETY: the pointer is valid for the life of self.
        unsafe { self.ptr.as_ref() }
    }

    /// Bytes of the model's array buffer (`mjModel.nbuffer`).
    pub fn buffer_bytes(&self) -> usize {
        self.m().nbuffer as usize
    }

    /// Bytes of the `mjData` arena (contacts, constraints and the stack) that each new
    /// simulation allocates (`mjModel.narena`, MJCF `<size memory="..."/>`).
    pub fn arena_bytes(&self) -> usize {
        self.m().narena as usize
    }

    /// Sets the arena size of simulations made from now on (`mjModel.narena`, read only by
    /// `mj_makeData`). Only possible before the model is shared.
    pub fn set_arena_bytes(&mut self, bytes: usize) {
        // SAFETY: `&mut self` proves no Simulation holds this model yet (they hold an Arc);
        // narena is a plain size field.
        unsafe { self.ptr.as_mut().narena = bytes as ffi::mjtSize };
    }

    /// Whether the arrays only rendering reads are still there (no
    /// [`Model::release_render_data`]): what [`crate::render::Renderer`] needs.
    pub fn has_render_data(&self) -> bool {
        !self.render_data_released
    }

    /// Bytes of the buffer given back to the OS by [`Model::release_render_data`].
    pub fn released_bytes(&self) -> usize {
        self.released_bytes
    }

    /// Gives back to the OS the pages of the arrays only rendering and ray casting read:
    /// texture pixels (`tex_data`), mesh normals, texture coordinates and faces (`mesh_normal`,
    /// `mesh_texcoord`, `mesh_face`, `mesh_facenormal`, `mesh_facetexcoord`), and the per-face
    /// bounding-volume trees of meshes (the `bvh_*` nodes past the bodies' own trees). In MuJoCo
    /// 3.3.7 the engine reads these only in `engine_ray.c`, `engine_vis_*.c`, `engine_print.c`
    /// and (mesh normals) the camera sensors of `engine_sensor.c`; collisions use the body trees
    /// (`body_bvhadr`), `mesh_vert`, `mesh_graph` and the `mesh_poly*` arrays, which stay. The
    /// released arrays' pointers are set to null so a reader would fault instead of seeing
    /// zeros. Skipped (returns 0) for models with sensors, flexes or dynamic trees, which may
    /// read them. Returns the bytes released; they no longer count in the process's RSS.
    ///
    /// Never call MuJoCo's ray, rendering, printing or `mj_copyModel` on such a model; this
    /// module offers none of them.
    pub fn release_render_data(&mut self) -> usize {
        let m = self.m();
        if m.nsensor > 0 || m.nflex > 0 || m.nbvhdynamic > 0 || self.render_data_released {
            return 0;
        }
        // SAFETY: body_bvhadr/body_bvhnum and mesh_bvhadr have nbody and nmesh entries.
        let (bvhadr, bvhnum, mesh_bvhadr) = unsafe {
            (
                slice(m.body_bvhadr, m.nbody as usize),
                slice(m.body_bvhnum, m.nbody as usize),
                slice(m.mesh_bvhadr, m.nmesh as usize),
            )
        };
        // Bodies' trees must all come before the first mesh tree for the tail to be mesh-only.
        let body_nodes = bvhadr
            .iter()
            .zip(bvhnum)
            .filter(|(_, n)| **n > 0)
            .map(|(a, n)| (a + n) as usize)
            .max()
            .unwrap_or(0);
        let tail_ok = mesh_bvhadr
            .iter()
            .filter(|a| **a >= 0)
            .all(|a| *a as usize >= body_nodes);
        let nbvh = m.nbvh as usize;
        let nface = 3 * m.nmeshface as usize;
        let spans: Vec<(*const u8, usize)> = {
            let mut v = vec![
                (m.tex_data.cast_const(), m.ntexdata as usize),
                (m.mesh_normal.cast(), 12 * m.nmeshnormal as usize),
                (m.mesh_texcoord.cast(), 8 * m.nmeshtexcoord as usize),
                (m.mesh_face.cast(), 4 * nface),
                (m.mesh_facenormal.cast(), 4 * nface),
                (m.mesh_facetexcoord.cast(), 4 * nface),
            ];
            if tail_ok && body_nodes < nbvh {
                let tail = nbvh - body_nodes;
                // SAFETY: pointer arithmetic only; each array has nbvh rows (bvh_aabb:
                // nbvhstatic = nbvh, as nbvhdynamic = 0 was checked above), so row `body_nodes`
                // is in bounds.
                unsafe {
                    v.push((m.bvh_depth.add(body_nodes).cast(), 4 * tail));
                    v.push((m.bvh_child.add(2 * body_nodes).cast(), 8 * tail));
                    v.push((m.bvh_nodeid.add(body_nodes).cast(), 4 * tail));
                    v.push((m.bvh_aabb.add(6 * body_nodes).cast(), 48 * tail));
                }
            }
            v
        };
        let mut released = 0;
        for (ptr, len) in spans {
            if ptr.is_null() || len == 0 {
                continue;
            }
            let start = (ptr as usize).div_ceil(PAGE) * PAGE;
            let end = (ptr as usize + len) / PAGE * PAGE;
            if end > start {
                // SAFETY: [start, end) lies inside one array of the model buffer, which this
                // Model owns exclusively (`&mut self`, before sharing); after this call nothing
                // reads it: the arrays' pointers are nulled below and the mesh-tree tail is
                // reached only through `mesh_bvhadr`, read only by ray casting and
                // visualisation. MADV_DONTNEED on private anonymous memory keeps the mapping
                // (later reads see zeros), so the allocator's bookkeeping stays valid.
                let rc = unsafe {
                    libc::madvise(start as *mut libc::c_void, end - start, libc::MADV_DONTNEED)
                };
                if rc == 0 {
                    released += end - start;
                }
            }
        }
        // SAFETY: `&mut self` before sharing; plain pointer fields.
        unsafe {
            let m = self.ptr.as_mut();
            m.tex_data = std::ptr::null_mut();
            m.mesh_normal = std::ptr::null_mut();
            m.mesh_texcoord = std::ptr::null_mut();
            m.mesh_face = std::ptr::null_mut();
            m.mesh_facenormal = std::ptr::null_mut();
            m.mesh_facetexcoord = std::ptr::null_mut();
        }
        self.released_bytes = released;
        self.render_data_released = true;
        released
    }
}

/// One simulation: its own `mjData` over a shared [`Model`].
pub struct Simulation {
    api: &'static ffi::MuJoCoLib,
    /// Keeps the shared buffer alive that most of `view`'s pointers read.
    shared: Arc<Model>,
    /// This simulation's copy of the `mjModel` struct (from `Box::into_raw`, freed in Drop):
    /// the shared model's pointers, except `body_pos`, `site_pos` and `eq_data`, which point
    /// into `overlay`. Every MuJoCo call gets this pointer.
    model: NonNull<ffi::mjModel>,
    /// Storage of the per-simulation model arrays: `body_pos` (3 × nbody), `site_pos`
    /// (3 × nsite), `eq_data` (mjNEQDATA × neq). Accessed only through `model`'s pointers.
    _overlay: Vec<f64>,
    data: NonNull<ffi::mjData>,
}

// SAFETY: a Simulation exclusively owns its mjData, its mjModel struct copy and overlay; the rest
// of the model is the Sync shared `Model`. MuJoCo functions touch only the model/data they are
// given, so moving the simulation to another thread is sound.
unsafe impl Send for Simulation {}

impl std::fmt::Debug for Simulation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulation")
            .field("nq", &self.m().nq)
            .field("nv", &self.m().nv)
            .field("nbody", &self.m().nbody)
            .finish()
    }
}

impl Drop for Simulation {
    fn drop(&mut self) {
        // SAFETY: data was created by mj_makeData for this Simulation and model by
        // Box::into_raw; each is freed once. The shared buffer is freed by Model's Drop.
        unsafe {
            self.api.mj_deleteData(self.data.as_ptr());
            drop(Box::from_raw(self.model.as_ptr()));
        }
    }
}

/// Builds a slice over a MuJoCo array. Callers pass lengths derived from the model's counts.
///
/// # Safety
/// `ptr` must point to at least `len` initialised elements that live as long as `'a`.
unsafe fn slice<'a, T>(ptr: *const T, len: usize) -> &'a [T] {
    if len == 0 || ptr.is_null() {
        &[]
    } else {
        // SAFETY: guaranteed by the caller.
        unsafe { std::slice::from_raw_parts(ptr, len) }
    }
}

/// # Safety
/// As [`slice`], and the memory must not be aliased for `'a`.
unsafe fn slice_mut<'a, T>(ptr: *mut T, len: usize) -> &'a mut [T] {
    if len == 0 || ptr.is_null() {
        &mut []
    } else {
        // SAFETY: guaranteed by the caller.
        unsafe { std::slice::from_raw_parts_mut(ptr, len) }
    }
}

fn vec3(s: &[f64], i: usize) -> [f64; 3] {
    [s[3 * i], s[3 * i + 1], s[3 * i + 2]]
}

impl Simulation {
    /// Compiles an MJCF file into a model of its own (see [`Model::from_xml`]).
    pub fn from_xml(path: &Path) -> Result<Self> {
        Self::new(&Arc::new(Model::from_xml(path)?))
    }

    /// A simulation over a shared model: new `mjData` in MuJoCo's default state (`mj_makeData`,
    /// arena of [`Model::arena_bytes`]) and fresh copies of the model's `body_pos`, `site_pos`
    /// and `eq_data`, which this simulation alone may change.
    pub fn new(model: &Arc<Model>) -> Result<Self> {
        let api = model.api;
        let m = model.m();
        let (nb, ns) = (3 * m.nbody as usize, 3 * m.nsite as usize);
        let ne = ffi::mjNEQDATA as usize * m.neq as usize;
        let mut overlay = Vec::with_capacity(nb + ns + ne);
        // SAFETY: body_pos, site_pos and eq_data have nb, ns and ne entries.
        unsafe {
            overlay.extend_from_slice(slice(m.body_pos, nb));
            overlay.extend_from_slice(slice(m.site_pos, ns));
            overlay.extend_from_slice(slice(m.eq_data, ne));
        }
        let mut view: ffi::mjModel = *m;
        let base = overlay.as_mut_ptr();
        // SAFETY: offsets within the overlay's nb + ns + ne entries. The Vec is never resized
        // nor borrowed again, so these pointers stay valid and unaliased for its life.
        unsafe {
            view.body_pos = base;
            view.site_pos = base.add(nb);
            view.eq_data = base.add(nb + ns);
        }
        let view = NonNull::from(Box::leak(Box::new(view)));
        // SAFETY: view is a valid model: the shared model's sizes and arrays with three arrays
        // replaced by copies of the same length.
        let data = unsafe { api.mj_makeData(view.as_ptr()) };
        let Some(data) = NonNull::new(data) else {
            // SAFETY: from Box::leak above, not used after this.
            drop(unsafe { Box::from_raw(view.as_ptr()) });
            return Err(SimError::Alloc { what: "mjData" });
        };
        Ok(Self {
            api,
            shared: Arc::clone(model),
            model: view,
            _overlay: overlay,
            data,
        })
    }

    /// The shared model this simulation steps.
    pub fn shared_model(&self) -> &Arc<Model> {
        &self.shared
    }

    /// The MuJoCo function table (for [`crate::render`]).
    pub(crate) fn api(&self) -> &'static ffi::MuJoCoLib {
        self.api
    }

    /// This simulation's model view (valid for the life of `self`; never written through).
    pub(crate) fn raw_model(&self) -> *const ffi::mjModel {
        self.model.as_ptr()
    }

    /// This simulation's `mjData` (valid for the life of `self`; [`crate::render`] only reads
    /// it).
    pub(crate) fn raw_data(&self) -> *const ffi::mjData {
        self.data.as_ptr()
    }

    fn m(&self) -> &ffi::mjModel {
        // SAFETY: the model pointer is valid for the life of self.
        unsafe { self.model.as_ref() }
    }
    fn d(&self) -> &ffi::mjData {
        // SAFETY: the data pointer is valid for the life of self.
        unsafe { self.data.as_ref() }
    }

    // ------------------------------------------------------------------ dynamics

    /// One physics step (`mj_step`).
    pub fn step(&mut self) {
        // SAFETY: model and data belong together and are exclusively borrowed.
        unsafe { self.api.mj_step(self.model.as_ptr(), self.data.as_ptr()) }
    }

    /// `n` physics steps.
    pub fn step_n(&mut self, n: usize) {
        for _ in 0..n {
            self.step();
        }
    }

    /// Recomputes all derived quantities from the state (`mj_forward`).
    pub fn forward(&mut self) {
        // SAFETY: as in `step`.
        unsafe { self.api.mj_forward(self.model.as_ptr(), self.data.as_ptr()) }
    }

    /// Position kinematics only (`mj_kinematics`): body, geom and site poses from qpos and the
    /// mocap poses. Far cheaper than `mj_forward` (no collision or constraint solve).
    pub fn kinematics(&mut self) {
        // SAFETY: as in `step`.
        unsafe {
            self.api
                .mj_kinematics(self.model.as_ptr(), self.data.as_ptr())
        }
    }

    /// Resets the data to the model defaults (`mj_resetData`).
    pub fn reset_data(&mut self) {
        // SAFETY: as in `step`.
        unsafe {
            self.api
                .mj_resetData(self.model.as_ptr(), self.data.as_ptr())
        }
    }

    /// Simulated time in seconds.
    pub fn time(&self) -> f64 {
        self.d().time
    }

    /// Model timestep in seconds.
    pub fn timestep(&self) -> f64 {
        self.m().opt.timestep
    }

    /// How often each MuJoCo warning kind fired since the last reset (index = `mjtWarning`).
    pub fn warning_counts(&self) -> [i32; ffi::mjNWARNING as usize] {
        let mut out = [0; ffi::mjNWARNING as usize];
        for (o, w) in out.iter_mut().zip(self.d().warning.iter()) {
            *o = w.number;
        }
        out
    }

    /// Total count of the warnings that mean the state went bad (non-finite qpos/qvel/qacc).
    pub fn instability_count(&self) -> i64 {
        let w = self.warning_counts();
        UNSTABLE_WARNINGS.iter().map(|&i| i64::from(w[i])).sum()
    }

    /// Total count of the warnings that mean the arena ran out and MuJoCo dropped contacts or
    /// constraints (`mjWARN_CONTACTFULL`, `mjWARN_CNSTRFULL`) since the last reset.
    pub fn arena_overflow_count(&self) -> i64 {
        let w = self.warning_counts();
        ARENA_WARNINGS.iter().map(|&i| i64::from(w[i])).sum()
    }

    /// Size of this simulation's arena in bytes (`mjData.narena`).
    pub fn arena_bytes(&self) -> usize {
        self.d().narena as usize
    }

    /// Peak arena use since the last reset in bytes, stack included (`mjData.maxuse_arena`).
    pub fn arena_peak_bytes(&self) -> usize {
        self.d().maxuse_arena as usize
    }

    /// Peak contacts and constraint rows since the last reset (`maxuse_con`, `maxuse_efc`).
    pub fn peak_contacts_constraints(&self) -> (usize, usize) {
        let d = self.d();
        (d.maxuse_con.max(0) as usize, d.maxuse_efc.max(0) as usize)
    }

    // ------------------------------------------------------------------ names

    /// Id of a named object (`mj_name2id`).
    ///
    /// # Errors
    /// [`SimError::UnknownName`] if the model has no object of that kind and name (or the name
    /// contains a NUL byte).
    pub fn id(&self, kind: ObjKind, name: &str) -> Result<usize> {
        let unknown = || SimError::UnknownName {
            kind: kind.label(),
            name: name.to_string(),
        };
        let cname = CString::new(name).map_err(|_| unknown())?;
        // SAFETY: model valid, cname NUL-terminated.
        let id = unsafe {
            self.api
                .mj_name2id(self.model.as_ptr(), kind.raw(), cname.as_ptr())
        };
        usize::try_from(id).map_err(|_| unknown())
    }
    /// Id of the body called `name`: [`Simulation::id`] with [`ObjKind::Body`].
    ///
    /// # Errors
    /// [`SimError::UnknownName`] if the model has no such body.
    pub fn body(&self, name: &str) -> Result<usize> {
        self.id(ObjKind::Body, name)
    }
    /// Id of the site called `name`: [`Simulation::id`] with [`ObjKind::Site`].
    ///
    /// # Errors
    /// [`SimError::UnknownName`] if the model has no such site.
    pub fn site(&self, name: &str) -> Result<usize> {
        self.id(ObjKind::Site, name)
    }
    /// Id of the geom called `name`: [`Simulation::id`] with [`ObjKind::Geom`].
    ///
    /// # Errors
    /// [`SimError::UnknownName`] if the model has no such geom.
    pub fn geom(&self, name: &str) -> Result<usize> {
        self.id(ObjKind::Geom, name)
    }
    /// Id of the joint called `name`: [`Simulation::id`] with [`ObjKind::Joint`].
    ///
    /// # Errors
    /// [`SimError::UnknownName`] if the model has no such joint.
    pub fn joint(&self, name: &str) -> Result<usize> {
        self.id(ObjKind::Joint, name)
    }

    // ------------------------------------------------------------------ sizes

    /// Number of generalised coordinates, the length of `qpos` (`mjModel.nq`).
    pub fn nq(&self) -> usize {
        self.m().nq as usize
    }
    /// Number of degrees of freedom, the length of `qvel` (`mjModel.nv`).
    pub fn nv(&self) -> usize {
        self.m().nv as usize
    }
    /// Number of actuators, the length of `ctrl` (`mjModel.nu`).
    pub fn nu(&self) -> usize {
        self.m().nu as usize
    }
    /// Number of actuator activation states, the length of `act` (`mjModel.na`).
    pub fn na(&self) -> usize {
        self.m().na as usize
    }
    /// Number of bodies, the world body included (`mjModel.nbody`).
    pub fn nbody(&self) -> usize {
        self.m().nbody as usize
    }
    /// Number of mocap bodies (`mjModel.nmocap`).
    pub fn nmocap(&self) -> usize {
        self.m().nmocap as usize
    }
    /// Number of sites (`mjModel.nsite`).
    pub fn nsite(&self) -> usize {
        self.m().nsite as usize
    }
    /// Number of geoms (`mjModel.ngeom`).
    pub fn ngeom(&self) -> usize {
        self.m().ngeom as usize
    }
    /// Number of joints (`mjModel.njnt`).
    pub fn njnt(&self) -> usize {
        self.m().njnt as usize
    }
    /// Number of equality constraints (`mjModel.neq`).
    pub fn neq(&self) -> usize {
        self.m().neq as usize
    }

    // ------------------------------------------------------------------ state (mjData)

    /// Generalised positions (`mjData.qpos`, length [`Simulation::nq`]).
    pub fn qpos(&self) -> &[f64] {
        // SAFETY: qpos has nq entries.
        unsafe { slice(self.d().qpos, self.nq()) }
    }
    /// Mutable generalised positions (`mjData.qpos`, length [`Simulation::nq`]); derived
    /// quantities are stale until the next [`Simulation::forward`] or [`Simulation::kinematics`].
    pub fn qpos_mut(&mut self) -> &mut [f64] {
        let n = self.nq();
        // SAFETY: qpos has nq entries; &mut self guarantees exclusivity.
        unsafe { slice_mut(self.data.as_ref().qpos, n) }
    }
    /// Generalised velocities (`mjData.qvel`, length [`Simulation::nv`]).
    pub fn qvel(&self) -> &[f64] {
        // SAFETY: qvel has nv entries.
        unsafe { slice(self.d().qvel, self.nv()) }
    }
    /// Mutable generalised velocities (`mjData.qvel`, length [`Simulation::nv`]).
    pub fn qvel_mut(&mut self) -> &mut [f64] {
        let n = self.nv();
        // SAFETY: qvel has nv entries; exclusive.
        unsafe { slice_mut(self.data.as_ref().qvel, n) }
    }
    /// Mutable actuator activations (`mjData.act`, length [`Simulation::na`]).
    pub fn act_mut(&mut self) -> &mut [f64] {
        let n = self.na();
        // SAFETY: act has na entries; exclusive.
        unsafe { slice_mut(self.data.as_ref().act, n) }
    }
    /// Mutable actuator controls (`mjData.ctrl`, length [`Simulation::nu`]), read by the next
    /// `mj_step`.
    pub fn ctrl_mut(&mut self) -> &mut [f64] {
        let n = self.nu();
        // SAFETY: ctrl has nu entries; exclusive.
        unsafe { slice_mut(self.data.as_ref().ctrl, n) }
    }
    /// Mocap body positions in world coordinates, metres (`mjData.mocap_pos`, `[nmocap, 3]`
    /// row-major).
    pub fn mocap_pos(&self) -> &[f64] {
        // SAFETY: mocap_pos has 3*nmocap entries.
        unsafe { slice(self.d().mocap_pos, 3 * self.nmocap()) }
    }
    /// Mutable mocap body positions, metres (`mjData.mocap_pos`, `[nmocap, 3]` row-major).
    pub fn mocap_pos_mut(&mut self) -> &mut [f64] {
        let n = 3 * self.nmocap();
        // SAFETY: mocap_pos has 3*nmocap entries; exclusive.
        unsafe { slice_mut(self.data.as_ref().mocap_pos, n) }
    }
    /// Mocap body orientations as (w, x, y, z) quaternions (`mjData.mocap_quat`, 4 per mocap
    /// body).
    pub fn mocap_quat(&self) -> &[f64] {
        let n = 4 * self.nmocap();
        // SAFETY: mocap_quat has 4*nmocap entries.
        unsafe { slice(self.d().mocap_quat, n) }
    }
    /// Mutable mocap body orientations as (w, x, y, z) quaternions (`mjData.mocap_quat`,
    /// `[nmocap, 4]` row-major; MuJoCo normalises them).
    pub fn mocap_quat_mut(&mut self) -> &mut [f64] {
        let n = 4 * self.nmocap();
        // SAFETY: mocap_quat has 4*nmocap entries; exclusive.
        unsafe { slice_mut(self.data.as_ref().mocap_quat, n) }
    }
    fn xpos_all(&self) -> &[f64] {
        // SAFETY: xpos has 3*nbody entries.
        unsafe { slice(self.d().xpos, 3 * self.nbody()) }
    }
    /// World position of a body frame (`data.body(name).xpos`).
    pub fn body_xpos(&self, body: usize) -> [f64; 3] {
        vec3(self.xpos_all(), body)
    }
    /// World orientation of a body frame as (w, x, y, z).
    pub fn body_xquat(&self, body: usize) -> [f64; 4] {
        // SAFETY: xquat has 4*nbody entries.
        let q = unsafe { slice(self.d().xquat, 4 * self.nbody()) };
        [
            q[4 * body],
            q[4 * body + 1],
            q[4 * body + 2],
            q[4 * body + 3],
        ]
    }
    /// World rotation matrix (row-major) of a body frame (`data.body(name).xmat`).
    pub fn body_xmat(&self, body: usize) -> [f64; 9] {
        // SAFETY: xmat has 9*nbody entries.
        let m = unsafe { slice(self.d().xmat, 9 * self.nbody()) };
        m[9 * body..9 * body + 9].try_into().expect("9 entries")
    }
    /// World position of a site.
    pub fn site_xpos(&self, site: usize) -> [f64; 3] {
        // SAFETY: site_xpos has 3*nsite entries.
        vec3(unsafe { slice(self.d().site_xpos, 3 * self.nsite()) }, site)
    }
    /// World rotation matrix (row-major) of a site.
    pub fn site_xmat(&self, site: usize) -> [f64; 9] {
        // SAFETY: site_xmat has 9*nsite entries.
        let m = unsafe { slice(self.d().site_xmat, 9 * self.nsite()) };
        m[9 * site..9 * site + 9].try_into().expect("9 entries")
    }
    /// Overwrites a site's world position in the data (until the next kinematics pass).
    pub fn set_site_xpos(&mut self, site: usize, pos: [f64; 3]) {
        let n = 3 * self.nsite();
        // SAFETY: site_xpos has 3*nsite entries; exclusive.
        let s = unsafe { slice_mut(self.data.as_ref().site_xpos, n) };
        s[3 * site..3 * site + 3].copy_from_slice(&pos);
    }
    /// World position of a geom.
    pub fn geom_xpos(&self, geom: usize) -> [f64; 3] {
        // SAFETY: geom_xpos has 3*ngeom entries.
        vec3(unsafe { slice(self.d().geom_xpos, 3 * self.ngeom()) }, geom)
    }
    /// World rotation matrix (row-major) of a geom.
    pub fn geom_xmat(&self, geom: usize) -> [f64; 9] {
        // SAFETY: geom_xmat has 9*ngeom entries.
        let m = unsafe { slice(self.d().geom_xmat, 9 * self.ngeom()) };
        m[9 * geom..9 * geom + 9].try_into().expect("9 entries")
    }
    /// Active contacts of the last kinematics/collision pass.
    pub fn contacts(&self) -> impl Iterator<Item = Contact> + '_ {
        // SAFETY: `contact` holds `ncon` initialised entries after mj_forward/mj_step.
        let cs = unsafe { slice(self.d().contact, self.d().ncon.max(0) as usize) };
        cs.iter().map(|c| Contact {
            geom1: c.geom[0],
            geom2: c.geom[1],
            efc_address: c.efc_address,
        })
    }
    /// Constraint forces of the last step (`efc_force`, length `nefc`).
    pub fn efc_force(&self) -> &[f64] {
        // SAFETY: efc_force has nefc entries.
        unsafe { slice(self.d().efc_force, self.d().nefc.max(0) as usize) }
    }

    // ------------------------------------------------------------------ model

    /// Body position relative to its parent (`model.body_pos`).
    pub fn body_pos(&self, body: usize) -> [f64; 3] {
        // SAFETY: body_pos has 3*nbody entries.
        vec3(unsafe { slice(self.m().body_pos, 3 * self.nbody()) }, body)
    }
    /// Sets a body's position relative to its parent in this simulation's own copy of
    /// `model.body_pos` (other simulations of the shared model are unaffected); takes effect at
    /// the next kinematics pass.
    pub fn set_body_pos(&mut self, body: usize, pos: [f64; 3]) {
        let n = 3 * self.nbody();
        // SAFETY: body_pos has 3*nbody entries; exclusive.
        let s = unsafe { slice_mut(self.model.as_ref().body_pos, n) };
        s[3 * body..3 * body + 3].copy_from_slice(&pos);
    }
    /// Mocap index of a body, if it is a mocap body.
    pub fn body_mocapid(&self, body: usize) -> Option<usize> {
        // SAFETY: body_mocapid has nbody entries.
        let ids = unsafe { slice(self.m().body_mocapid, self.nbody()) };
        usize::try_from(ids[body]).ok()
    }
    /// Site position relative to its body (`model.site_pos`).
    pub fn site_pos(&self, site: usize) -> [f64; 3] {
        // SAFETY: site_pos has 3*nsite entries.
        vec3(unsafe { slice(self.m().site_pos, 3 * self.nsite()) }, site)
    }
    /// Sets a site's position relative to its body in this simulation's own copy of
    /// `model.site_pos` (other simulations of the shared model are unaffected); takes effect at
    /// the next kinematics pass.
    pub fn set_site_pos(&mut self, site: usize, pos: [f64; 3]) {
        let n = 3 * self.nsite();
        // SAFETY: site_pos has 3*nsite entries; exclusive.
        let s = unsafe { slice_mut(self.model.as_ref().site_pos, n) };
        s[3 * site..3 * site + 3].copy_from_slice(&pos);
    }
    /// Geom position relative to its body (`model.geom_pos`).
    pub fn geom_pos(&self, geom: usize) -> [f64; 3] {
        // SAFETY: geom_pos has 3*ngeom entries.
        vec3(unsafe { slice(self.m().geom_pos, 3 * self.ngeom()) }, geom)
    }
    /// Address of a joint's first coordinate in qpos.
    pub fn jnt_qposadr(&self, joint: usize) -> usize {
        // SAFETY: jnt_qposadr has njnt entries.
        (unsafe { slice(self.m().jnt_qposadr, self.njnt()) })[joint] as usize
    }
    /// Address of a joint's first degree of freedom in qvel.
    pub fn jnt_dofadr(&self, joint: usize) -> usize {
        // SAFETY: jnt_dofadr has njnt entries.
        (unsafe { slice(self.m().jnt_dofadr, self.njnt()) })[joint] as usize
    }
    /// Equality-constraint types (`mjtEq`), one per constraint.
    pub fn eq_type(&self) -> &[i32] {
        // SAFETY: eq_type has neq entries.
        unsafe { slice(self.m().eq_type, self.neq()) }
    }
    /// Equality-constraint data, `mjNEQDATA` values per constraint.
    pub fn eq_data_mut(&mut self) -> &mut [f64] {
        let n = ffi::mjNEQDATA as usize * self.neq();
        // SAFETY: eq_data has neq*mjNEQDATA entries; exclusive.
        unsafe { slice_mut(self.model.as_ref().eq_data, n) }
    }
}

impl Simulation {
    fn state_size(&self) -> usize {
        // SAFETY: model valid; the signature is a valid state signature.
        let n = unsafe {
            self.api
                .mj_stateSize(self.model.as_ptr(), ffi::mjSTATE_INTEGRATION)
        };
        n.max(0) as usize
    }

    /// MuJoCo's integration state (`mj_getState` with `mjSTATE_INTEGRATION`: time, qpos, qvel,
    /// act, warm start, controls, applied forces, mocap poses, ...): everything the next
    /// `mj_step` depends on besides the model.
    pub fn integration_state(&self, out: &mut Vec<f64>) {
        out.clear();
        out.resize(self.state_size(), 0.0);
        // SAFETY: `out` has exactly mj_stateSize entries for this signature.
        unsafe {
            self.api.mj_getState(
                self.model.as_ptr(),
                self.data.as_ptr(),
                out.as_mut_ptr(),
                ffi::mjSTATE_INTEGRATION,
            )
        };
    }

    /// Writes an integration state taken from a simulation of the same model (derived
    /// quantities are not recomputed). Returns false and changes nothing on a length mismatch.
    pub fn set_integration_state(&mut self, state: &[f64]) -> bool {
        if state.len() != self.state_size() {
            return false;
        }
        // SAFETY: `state` has exactly mj_stateSize entries for this signature.
        unsafe {
            self.api.mj_setState(
                self.model.as_ptr(),
                self.data.as_ptr(),
                state.as_ptr(),
                ffi::mjSTATE_INTEGRATION,
            )
        };
        true
    }

    /// Everything the next steps depend on, as exact bit patterns: MuJoCo's integration state
    /// (time, qpos, qvel, act, warm start, controls, applied forces, mocap poses, ...) and the
    /// body placements of the model, which tasks move at reset.
    pub fn dynamics_key(&self, out: &mut Vec<u64>) {
        let mut state = Vec::new();
        self.integration_state(&mut state);
        // SAFETY: body_pos and body_quat have 3*nbody and 4*nbody entries.
        let (pos, quat) = unsafe {
            (
                slice(self.m().body_pos, 3 * self.nbody()),
                slice(self.m().body_quat, 4 * self.nbody()),
            )
        };
        out.clear();
        out.extend(state.iter().chain(pos).chain(quat).map(|v| v.to_bits()));
    }
}

/// `mjtEq` value of a weld constraint.
pub const EQ_WELD: i32 = ffi::mjEQ_WELD as i32;
/// Values per equality constraint in `eq_data`.
pub const EQ_DATA_LEN: usize = ffi::mjNEQDATA as usize;
