//! A thin, safe wrapper over MuJoCo 3.3.7: one [`Simulation`] owns one `mjModel` and one `mjData`.
//!
//! This is the only module of the project with `unsafe`. The library is loaded once per process
//! (path baked in by `build.rs`, overridable with `TERL_MUJOCO_LIB`). Every pointer handed to
//! MuJoCo comes from a `Simulation` that owns it exclusively, and every slice we hand out is sized
//! from the model's own counts, so the safe API cannot read past MuJoCo's arrays.
#![allow(unsafe_code)]

use std::ffi::{c_char, CStr, CString};
use std::path::{Path, PathBuf};
use std::ptr::NonNull;
use std::sync::OnceLock;

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
    Body,
    Joint,
    Geom,
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
    pub geom1: i32,
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

/// One MuJoCo model with its data, owned exclusively.
pub struct Simulation {
    api: &'static ffi::MuJoCoLib,
    model: NonNull<ffi::mjModel>,
    data: NonNull<ffi::mjData>,
}

// SAFETY: a Simulation exclusively owns its mjModel and mjData; MuJoCo functions touch only the
// model/data they are given, so moving the pair to another thread is sound.
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
        // SAFETY: both pointers were created by MuJoCo for this Simulation and are freed once.
        unsafe {
            self.api.mj_deleteData(self.data.as_ptr());
            self.api.mj_deleteModel(self.model.as_ptr());
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
    /// Compiles an MJCF file.
    pub fn from_xml(path: &Path) -> Result<Self> {
        let api = api()?;
        let cpath =
            CString::new(path.to_string_lossy().as_bytes()).map_err(|_| SimError::ModelLoad {
                path: path.to_path_buf(),
                message: "path contains a NUL byte".into(),
            })?;
        let mut err = [0 as c_char; 1024];
        // SAFETY: cpath is NUL-terminated; err is a writable buffer of the size we pass.
        let model = unsafe {
            api.mj_loadXML(
                cpath.as_ptr(),
                std::ptr::null(),
                err.as_mut_ptr(),
                err.len() as i32,
            )
        };
        let Some(model) = NonNull::new(model) else {
            // SAFETY: MuJoCo NUL-terminates the error buffer.
            let message = unsafe { CStr::from_ptr(err.as_ptr()) }
                .to_string_lossy()
                .into_owned();
            return Err(SimError::ModelLoad {
                path: path.to_path_buf(),
                message,
            });
        };
        Self::with_model(api, model)
    }

    fn with_model(api: &'static ffi::MuJoCoLib, model: NonNull<ffi::mjModel>) -> Result<Self> {
        // SAFETY: model is a valid compiled model.
        let data = unsafe { api.mj_makeData(model.as_ptr()) };
        let Some(data) = NonNull::new(data) else {
            // SAFETY: model was allocated by MuJoCo and is not used after this.
            unsafe { api.mj_deleteModel(model.as_ptr()) };
            return Err(SimError::Alloc { what: "mjData" });
        };
        Ok(Self { api, model, data })
    }

    /// A fresh simulation with a deep copy of this model (including run-time model edits) and new
    /// data in MuJoCo's default state. Much cheaper than compiling the XML again.
    pub fn clone_model(&self) -> Result<Self> {
        // SAFETY: self.model is valid; a null destination asks MuJoCo to allocate.
        let model = unsafe {
            self.api
                .mj_copyModel(std::ptr::null_mut(), self.model.as_ptr())
        };
        let model = NonNull::new(model).ok_or(SimError::Alloc { what: "mjModel" })?;
        Self::with_model(self.api, model)
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

    // ------------------------------------------------------------------ names

    /// Id of a named object.
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
    pub fn body(&self, name: &str) -> Result<usize> {
        self.id(ObjKind::Body, name)
    }
    pub fn site(&self, name: &str) -> Result<usize> {
        self.id(ObjKind::Site, name)
    }
    pub fn geom(&self, name: &str) -> Result<usize> {
        self.id(ObjKind::Geom, name)
    }
    pub fn joint(&self, name: &str) -> Result<usize> {
        self.id(ObjKind::Joint, name)
    }

    // ------------------------------------------------------------------ sizes

    pub fn nq(&self) -> usize {
        self.m().nq as usize
    }
    pub fn nv(&self) -> usize {
        self.m().nv as usize
    }
    pub fn nu(&self) -> usize {
        self.m().nu as usize
    }
    pub fn na(&self) -> usize {
        self.m().na as usize
    }
    pub fn nbody(&self) -> usize {
        self.m().nbody as usize
    }
    pub fn nmocap(&self) -> usize {
        self.m().nmocap as usize
    }
    pub fn nsite(&self) -> usize {
        self.m().nsite as usize
    }
    pub fn ngeom(&self) -> usize {
        self.m().ngeom as usize
    }
    pub fn njnt(&self) -> usize {
        self.m().njnt as usize
    }
    pub fn neq(&self) -> usize {
        self.m().neq as usize
    }

    // ------------------------------------------------------------------ state (mjData)

    pub fn qpos(&self) -> &[f64] {
        // SAFETY: qpos has nq entries.
        unsafe { slice(self.d().qpos, self.nq()) }
    }
    pub fn qpos_mut(&mut self) -> &mut [f64] {
        let n = self.nq();
        // SAFETY: qpos has nq entries; &mut self guarantees exclusivity.
        unsafe { slice_mut(self.data.as_ref().qpos, n) }
    }
    pub fn qvel(&self) -> &[f64] {
        // SAFETY: qvel has nv entries.
        unsafe { slice(self.d().qvel, self.nv()) }
    }
    pub fn qvel_mut(&mut self) -> &mut [f64] {
        let n = self.nv();
        // SAFETY: qvel has nv entries; exclusive.
        unsafe { slice_mut(self.data.as_ref().qvel, n) }
    }
    pub fn act_mut(&mut self) -> &mut [f64] {
        let n = self.na();
        // SAFETY: act has na entries; exclusive.
        unsafe { slice_mut(self.data.as_ref().act, n) }
    }
    pub fn ctrl_mut(&mut self) -> &mut [f64] {
        let n = self.nu();
        // SAFETY: ctrl has nu entries; exclusive.
        unsafe { slice_mut(self.data.as_ref().ctrl, n) }
    }
    pub fn mocap_pos(&self) -> &[f64] {
        // SAFETY: mocap_pos has 3*nmocap entries.
        unsafe { slice(self.d().mocap_pos, 3 * self.nmocap()) }
    }
    pub fn mocap_pos_mut(&mut self) -> &mut [f64] {
        let n = 3 * self.nmocap();
        // SAFETY: mocap_pos has 3*nmocap entries; exclusive.
        unsafe { slice_mut(self.data.as_ref().mocap_pos, n) }
    }
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
