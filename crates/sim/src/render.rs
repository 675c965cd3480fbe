//! Offscreen rendering of a simulation's scene from one of its named cameras, with MuJoCo's own
//! renderer (`mjv_updateScene`, `mjr_render`, `mjr_readPixels` of the same libmujoco 3.3.7) in
//! a headless OpenGL context made with EGL on Mesa's surfaceless platform (llvmpipe: no GPU, no
//! display, no X server). The same calls, in the same order, as Python MuJoCo's
//! `mujoco.Renderer` with `MUJOCO_GL=egl` (`mujoco/renderer.py`, `mujoco/egl/__init__.py`).
//!
//! A [`Renderer`] belongs to the thread that made it (its GL context is current there) and to
//! one model: it uploads that model's meshes and textures once. It never touches the simulation
//! it draws: the state (`qpos`, `qvel`, `act`, mocap poses, time) is copied into the renderer's
//! own `mjData`, where `mj_forward` computes the poses to draw, so a rendered episode steps
//! exactly like an unrendered one.
//!
//! The model must keep the arrays only rendering reads: environments built with
//! [`crate::Env::for_rendering`], not the shared models of training
//! ([`crate::Model::release_render_data`]).
//!
//! System libraries: `libEGL.so.1` (Debian `libegl1`) with Mesa's EGL and software driver
//! (`libegl-mesa0`, `libgl1-mesa-dri`), all installed by `deploy/setup.sh`.
#![allow(unsafe_code)]

use std::ffi::{c_char, c_int, c_uint, c_void, CStr};
use std::ptr::NonNull;
use std::sync::{Arc, OnceLock};

use crate::error::{Result, SimError};
use crate::ffi;
use crate::mujoco::{Model, Simulation};

/// Largest frame side, pixels: Mesa's llvmpipe renderbuffers go to 16384, but an offscreen
/// buffer that MuJoCo cannot allocate ends the process (`mju_error`), so stay well inside.
pub const MAX_SIDE: u32 = 4096;
/// Geoms the scene holds (Python `mujoco.Renderer`'s default `max_geom`).
const MAX_GEOM: c_int = 10_000;

/// One rendered image: `width × height` RGB pixels, 8 bits per channel, the top row first.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// Pixels per row.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// `3 × width × height` bytes, row-major from the top-left corner.
    pub rgb: Vec<u8>,
}

// ---------------------------------------------------------------------------------------- EGL

type EglDisplay = *mut c_void;
type EglConfig = *mut c_void;
type EglContext = *mut c_void;
type EglBoolean = c_uint;
type EglInt = i32;

const EGL_NONE: EglInt = 0x3038;
const EGL_RED_SIZE: EglInt = 0x3024;
const EGL_GREEN_SIZE: EglInt = 0x3023;
const EGL_BLUE_SIZE: EglInt = 0x3022;
const EGL_ALPHA_SIZE: EglInt = 0x3021;
const EGL_DEPTH_SIZE: EglInt = 0x3025;
const EGL_STENCIL_SIZE: EglInt = 0x3026;
const EGL_COLOR_BUFFER_TYPE: EglInt = 0x303F;
const EGL_RGB_BUFFER: EglInt = 0x308E;
const EGL_SURFACE_TYPE: EglInt = 0x3033;
const EGL_PBUFFER_BIT: EglInt = 0x0001;
const EGL_RENDERABLE_TYPE: EglInt = 0x3040;
const EGL_OPENGL_BIT: EglInt = 0x0008;
const EGL_OPENGL_API: c_uint = 0x30A2;
const EGL_PLATFORM_SURFACELESS_MESA: c_uint = 0x31DD;

/// The EGL entry points used, resolved from `libEGL.so.1`.
struct Egl {
    _lib: libloading::os::unix::Library,
    get_error: unsafe extern "C" fn() -> EglInt,
    bind_api: unsafe extern "C" fn(c_uint) -> EglBoolean,
    create_context:
        unsafe extern "C" fn(EglDisplay, EglConfig, EglContext, *const EglInt) -> EglContext,
    make_current:
        unsafe extern "C" fn(EglDisplay, *mut c_void, *mut c_void, EglContext) -> EglBoolean,
    destroy_context: unsafe extern "C" fn(EglDisplay, EglContext) -> EglBoolean,
    /// The surfaceless display, initialised once and kept for the life of the process (EGL
    /// displays are not reference counted: terminating it would end every renderer's context).
    display: EglDisplay,
    config: EglConfig,
}

// SAFETY: `Egl` is immutable after `load_egl`: function pointers into a library that stays
// loaded, and EGL handles that EGL allows to be used from any thread (a context is current on
// one thread at a time, which `Renderer` ensures by being neither Send nor Sync).
unsafe impl Send for Egl {}
// SAFETY: see above.
unsafe impl Sync for Egl {}

static EGL: OnceLock<std::result::Result<Egl, String>> = OnceLock::new();

const GL_PACKAGES: &str =
    "install Debian's libegl1, libegl-mesa0 and libgl1-mesa-dri (./deploy/setup.sh does)";

fn gl_error(reason: impl Into<String>) -> SimError {
    SimError::Render {
        reason: format!("{}; {GL_PACKAGES}", reason.into()),
    }
}

fn load_egl() -> std::result::Result<Egl, String> {
    // RTLD_GLOBAL: MuJoCo's GL loader (glad, inside libmujoco) looks `eglGetProcAddress` up in
    // the process's global symbols.
    // SAFETY: libEGL's initialisers have no preconditions; symbols are checked below.
    let lib = unsafe {
        libloading::os::unix::Library::open(Some("libEGL.so.1"), libc::RTLD_NOW | libc::RTLD_GLOBAL)
    }
    .map_err(|e| format!("cannot load libEGL.so.1 ({e})"))?;
    macro_rules! sym {
        ($name:literal) => {
            // SAFETY: the type written at each use is the EGL 1.5 signature of that function.
            *unsafe { lib.get(concat!($name, "\0").as_bytes()) }
                .map_err(|e| format!("libEGL.so.1 has no {} ({e})", $name))?
        };
    }
    let get_platform_display: unsafe extern "C" fn(
        c_uint,
        *mut c_void,
        *const isize,
    ) -> EglDisplay = sym!("eglGetPlatformDisplay");
    let get_error: unsafe extern "C" fn() -> EglInt = sym!("eglGetError");
    let initialize: unsafe extern "C" fn(EglDisplay, *mut EglInt, *mut EglInt) -> EglBoolean =
        sym!("eglInitialize");
    let choose_config: unsafe extern "C" fn(
        EglDisplay,
        *const EglInt,
        *mut EglConfig,
        EglInt,
        *mut EglInt,
    ) -> EglBoolean = sym!("eglChooseConfig");
    let bind_api: unsafe extern "C" fn(c_uint) -> EglBoolean = sym!("eglBindAPI");
    let create_context: unsafe extern "C" fn(
        EglDisplay,
        EglConfig,
        EglContext,
        *const EglInt,
    ) -> EglContext = sym!("eglCreateContext");
    let make_current: unsafe extern "C" fn(
        EglDisplay,
        *mut c_void,
        *mut c_void,
        EglContext,
    ) -> EglBoolean = sym!("eglMakeCurrent");
    let destroy_context: unsafe extern "C" fn(EglDisplay, EglContext) -> EglBoolean =
        sym!("eglDestroyContext");

    // SAFETY: EGL_DEFAULT_DISPLAY (null) and no attributes are valid for the surfaceless
    // platform of EGL_MESA_platform_surfaceless.
    let display = unsafe {
        get_platform_display(
            EGL_PLATFORM_SURFACELESS_MESA,
            std::ptr::null_mut(),
            std::ptr::null(),
        )
    };
    if display.is_null() {
        // SAFETY: no preconditions.
        let code = unsafe { get_error() };
        return Err(format!(
            "EGL has no surfaceless display (eglGetPlatformDisplay error {code:#x}: Mesa's EGL \
             is missing)"
        ));
    }
    let (mut major, mut minor) = (0, 0);
    // SAFETY: display came from eglGetPlatformDisplay; the out pointers are valid.
    if unsafe { initialize(display, &mut major, &mut minor) } == 0 {
        // SAFETY: no preconditions.
        let code = unsafe { get_error() };
        return Err(format!("eglInitialize failed (error {code:#x})"));
    }
    let attributes = [
        EGL_RED_SIZE,
        8,
        EGL_GREEN_SIZE,
        8,
        EGL_BLUE_SIZE,
        8,
        EGL_ALPHA_SIZE,
        8,
        EGL_DEPTH_SIZE,
        24,
        EGL_STENCIL_SIZE,
        8,
        EGL_COLOR_BUFFER_TYPE,
        EGL_RGB_BUFFER,
        EGL_SURFACE_TYPE,
        EGL_PBUFFER_BIT,
        EGL_RENDERABLE_TYPE,
        EGL_OPENGL_BIT,
        EGL_NONE,
    ];
    let mut config: EglConfig = std::ptr::null_mut();
    let mut found: EglInt = 0;
    // SAFETY: initialised display; the attribute list ends with EGL_NONE; room for one config.
    let ok = unsafe { choose_config(display, attributes.as_ptr(), &mut config, 1, &mut found) };
    if ok == 0 || found < 1 {
        return Err(
            "EGL offers no 8-bit RGBA OpenGL configuration with a 24-bit depth buffer".into(),
        );
    }
    Ok(Egl {
        _lib: lib,
        get_error,
        bind_api,
        create_context,
        make_current,
        destroy_context,
        display,
        config,
    })
}

fn egl() -> Result<&'static Egl> {
    EGL.get_or_init(load_egl).as_ref().map_err(gl_error)
}

// ---------------------------------------------------------------------------------- renderer

/// Draws one model's scenes offscreen at a fixed size (see the module docs).
pub struct Renderer {
    api: &'static ffi::MuJoCoLib,
    egl: &'static Egl,
    context: NonNull<c_void>,
    /// The model drawn, kept alive: a simulation of another model is refused.
    model: Arc<Model>,
    /// Scratch state: the drawn simulation's state is copied here and `mj_forward` run on it.
    data: NonNull<ffi::mjData>,
    scene: Box<ffi::mjvScene>,
    context_mj: Box<ffi::mjrContext>,
    option: Box<ffi::mjvOption>,
    cameras: Vec<String>,
    width: u32,
    height: u32,
    pixels: Vec<u8>,
    /// World z of the last rendered camera's up axis (its y axis): below 0 it sees upside down.
    up_z: f64,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("cameras", &self.cameras)
            .finish()
    }
}

impl Renderer {
    /// A renderer of `sim`'s model at `width × height` pixels (each in `1..=`[`MAX_SIDE`]).
    /// A failure inside MuJoCo's own GL set-up (`mjr_makeContext`) is fatal in MuJoCo
    /// (`mju_error`): the process ends with its message, as for any MuJoCo error.
    ///
    /// # Errors
    /// [`SimError::Render`] when EGL or Mesa's OpenGL is missing (naming the Debian packages),
    /// when the size is out of range, or when the model gave back its rendering arrays;
    /// [`SimError::Alloc`] when MuJoCo cannot allocate the scratch `mjData`.
    pub fn new(sim: &Simulation, width: u32, height: u32) -> Result<Self> {
        if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
            return Err(SimError::Render {
                reason: format!(
                    "frame size {width}x{height} is outside 1..={MAX_SIDE} pixels per side"
                ),
            });
        }
        if !sim.shared_model().has_render_data() {
            return Err(SimError::Render {
                reason: "this simulation's model gave back the arrays rendering reads (meshes' \
                         faces, textures): build the environment with Env::for_rendering"
                    .into(),
            });
        }
        let api = sim.api();
        let egl = egl()?;
        // SAFETY: EGL_OPENGL_API is a valid API enum.
        if unsafe { (egl.bind_api)(EGL_OPENGL_API) } == 0 {
            return Err(gl_error("EGL cannot bind the desktop OpenGL API"));
        }
        // SAFETY: display and config come from load_egl; no share context, no attributes (a
        // compatibility-profile context, which MuJoCo's fixed-function renderer needs).
        let context = unsafe {
            (egl.create_context)(
                egl.display,
                egl.config,
                std::ptr::null_mut(),
                [EGL_NONE].as_ptr(),
            )
        };
        let Some(context) = NonNull::new(context) else {
            // SAFETY: no preconditions.
            let code = unsafe { (egl.get_error)() };
            return Err(gl_error(format!(
                "eglCreateContext failed (error {code:#x})"
            )));
        };
        let destroy = |why: String| {
            // SAFETY: the context was created above and is not current on another thread.
            unsafe {
                (egl.make_current)(
                    egl.display,
                    std::ptr::null_mut(),
                    std::ptr::null_mut(),
                    std::ptr::null_mut(),
                );
                (egl.destroy_context)(egl.display, context.as_ptr());
            }
            gl_error(why)
        };
        // SAFETY: surfaceless context (EGL_KHR_surfaceless_context, part of Mesa's platform).
        let current = unsafe {
            (egl.make_current)(
                egl.display,
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                context.as_ptr(),
            )
        };
        if current == 0 {
            // SAFETY: no preconditions.
            let code = unsafe { (egl.get_error)() };
            return Err(destroy(format!("eglMakeCurrent failed (error {code:#x})")));
        }
        // A model view whose offscreen buffer has the frame's size (MuJoCo sizes it from
        // `vis.global.offwidth/offheight` in mjr_makeContext); every array pointer is shared.
        // SAFETY: the simulation's model view is valid for the duration of this call.
        let mut view: ffi::mjModel = unsafe { *sim.raw_model() };
        view.vis.global.offwidth = width as c_int;
        view.vis.global.offheight = height as c_int;
        let mut scene: Box<ffi::mjvScene> = Box::default();
        let mut option: Box<ffi::mjvOption> = Box::default();
        let mut context_mj: Box<ffi::mjrContext> = Box::default();
        // SAFETY: default-initialise then allocate MuJoCo's scene and GL context for a valid
        // model with a current OpenGL context (checked above); each is freed once in Drop.
        unsafe {
            api.mjv_defaultScene(&mut *scene);
            api.mjv_makeScene(&view, &mut *scene, MAX_GEOM);
            api.mjv_defaultOption(&mut *option);
            api.mjr_defaultContext(&mut *context_mj);
            api.mjr_makeContext(&view, &mut *context_mj, ffi::mjFONTSCALE_150 as c_int);
            api.mjr_setBuffer(ffi::mjFB_OFFSCREEN as c_int, &mut *context_mj);
        }
        if context_mj.offWidth < width as c_int || context_mj.offHeight < height as c_int {
            let (w, h) = (context_mj.offWidth, context_mj.offHeight);
            // SAFETY: made above, freed once.
            unsafe {
                api.mjr_freeContext(&mut *context_mj);
                api.mjv_freeScene(&mut *scene);
            }
            return Err(destroy(format!(
                "MuJoCo made a {w}x{h} offscreen buffer, smaller than {width}x{height}"
            )));
        }
        // SAFETY: a valid model view; null means out of memory.
        let data = unsafe { api.mj_makeData(sim.raw_model()) };
        let Some(data) = NonNull::new(data) else {
            // SAFETY: made above, freed once.
            unsafe {
                api.mjr_freeContext(&mut *context_mj);
                api.mjv_freeScene(&mut *scene);
            }
            drop(destroy(String::new()));
            return Err(SimError::Alloc {
                what: "the renderer's mjData",
            });
        };
        let cameras = camera_names(api, sim.raw_model());
        Ok(Self {
            api,
            egl,
            context,
            model: Arc::clone(sim.shared_model()),
            data,
            scene,
            context_mj,
            option,
            cameras,
            width,
            height,
            pixels: vec![0; 3 * width as usize * height as usize],
            up_z: 1.0,
        })
    }

    /// The model's named cameras, in model order (Meta-World: `topview`, `corner`, `corner2`,
    /// `corner3`, `behindGripper`, `gripperPOV`, ...).
    pub fn cameras(&self) -> &[String] {
        &self.cameras
    }

    /// Frame width, pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Frame height, pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Renders `sim`'s current state from the named camera. `sim` is only read.
    ///
    /// # Errors
    /// [`SimError::Render`] for a camera the model does not have (the message lists them), a
    /// simulation of another model, or a GL context that cannot be made current.
    pub fn render(&mut self, sim: &Simulation, camera: &str) -> Result<Frame> {
        if !Arc::ptr_eq(sim.shared_model(), &self.model) {
            return Err(SimError::Render {
                reason: "this renderer was made for another model (one renderer per task)".into(),
            });
        }
        let Some(camera_id) = self.cameras.iter().position(|c| c == camera) else {
            return Err(SimError::Render {
                reason: format!(
                    "no camera {camera:?} in this scene; its cameras: {}",
                    self.cameras.join(", ")
                ),
            });
        };
        let egl = self.egl;
        // SAFETY: our context, used only on this thread (Renderer is !Send).
        let current = unsafe {
            (egl.make_current)(
                egl.display,
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                self.context.as_ptr(),
            )
        };
        if current == 0 {
            // SAFETY: no preconditions.
            let code = unsafe { (egl.get_error)() };
            return Err(gl_error(format!("eglMakeCurrent failed (error {code:#x})")));
        }
        let m = sim.raw_model();
        // SAFETY: the scratch data was made for this model (checked by model_key above), so
        // every array has the same length as the source's; the source is only read.
        unsafe {
            let (src, dst) = (&*sim.raw_data(), self.data.as_mut());
            let mm = &*m;
            copy(src.qpos, dst.qpos, mm.nq as usize);
            copy(src.qvel, dst.qvel, mm.nv as usize);
            copy(src.act, dst.act, mm.na as usize);
            copy(src.mocap_pos, dst.mocap_pos, 3 * mm.nmocap as usize);
            copy(src.mocap_quat, dst.mocap_quat, 4 * mm.nmocap as usize);
            copy(src.ctrl, dst.ctrl, mm.nu as usize);
            dst.time = src.time;
            self.api.mj_forward(m, self.data.as_ptr());
            // cam_xmat: 9 per camera, row-major camera-to-world rotation; its second column is
            // the camera's up axis in world coordinates.
            let xmat = self.data.as_ref().cam_xmat;
            self.up_z = *xmat.add(9 * camera_id + 7);
        }
        let mut cam = ffi::mjvCamera {
            type_: ffi::mjCAMERA_FIXED as c_int,
            fixedcamid: camera_id as c_int,
            ..Default::default()
        };
        let rect = ffi::mjrRect {
            left: 0,
            bottom: 0,
            width: self.width as c_int,
            height: self.height as c_int,
        };
        // SAFETY: model, scratch data, option, camera and scene are valid and belong together;
        // the GL context is current; the pixel buffer holds 3 × width × height bytes.
        unsafe {
            self.api.mjv_updateScene(
                m,
                self.data.as_ptr(),
                &*self.option,
                std::ptr::null(),
                &mut cam,
                ffi::mjCAT_ALL as c_int,
                &mut *self.scene,
            );
            self.api
                .mjr_render(rect, &mut *self.scene, &*self.context_mj);
            self.api.mjr_readPixels(
                self.pixels.as_mut_ptr(),
                std::ptr::null_mut(),
                rect,
                &*self.context_mj,
            );
        }
        // OpenGL's rows go bottom-up.
        let row = 3 * self.width as usize;
        let mut rgb = Vec::with_capacity(self.pixels.len());
        for r in self.pixels.chunks_exact(row).rev() {
            rgb.extend_from_slice(r);
        }
        Ok(Frame {
            width: self.width,
            height: self.height,
            rgb,
        })
    }
}

impl Renderer {
    /// [`Renderer::render`] turned the right way up for people: a camera whose up axis points
    /// below the horizon (world z of its y axis < 0; Meta-World's `corner` and `corner2`, whose
    /// frames MuJoCo, like Python Meta-World, draws upside down) has its frame rotated by 180°.
    ///
    /// # Errors
    /// As [`Renderer::render`].
    pub fn render_upright(&mut self, sim: &Simulation, camera: &str) -> Result<Frame> {
        let mut frame = self.render(sim, camera)?;
        if self.up_z < 0.0 {
            frame.rotate_half_turn();
        }
        Ok(frame)
    }
}

impl Frame {
    /// Rotates the image by 180° in place (the last pixel first).
    pub fn rotate_half_turn(&mut self) {
        self.rgb.reverse();
        for px in self.rgb.chunks_exact_mut(3) {
            px.reverse();
        }
    }
}

impl Drop for Renderer {
    fn drop(&mut self) {
        let egl = self.egl;
        // SAFETY: everything was made in `new` and is freed once; MuJoCo's GL objects only with
        // our context current (mjr_freeContext deletes GL objects in the current context: if
        // ours cannot be made current they are left to the context's destruction); the context
        // is destroyed last.
        unsafe {
            let current = (egl.make_current)(
                egl.display,
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                self.context.as_ptr(),
            );
            if current != 0 {
                self.api.mjr_freeContext(&mut *self.context_mj);
            }
            self.api.mjv_freeScene(&mut *self.scene);
            self.api.mj_deleteData(self.data.as_ptr());
            (egl.make_current)(
                egl.display,
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
            );
            (egl.destroy_context)(egl.display, self.context.as_ptr());
        }
    }
}

/// # Safety
/// `src` and `dst` point to at least `n` values (either may be null when `n` is 0).
unsafe fn copy(src: *const f64, dst: *mut f64, n: usize) {
    if n > 0 && !src.is_null() && !dst.is_null() {
        // SAFETY: guaranteed by the caller; distinct mjData, so no overlap.
        unsafe { std::ptr::copy_nonoverlapping(src, dst, n) };
    }
}

fn camera_names(api: &ffi::MuJoCoLib, m: *const ffi::mjModel) -> Vec<String> {
    // SAFETY: m is a valid model; ncam bounds the ids asked for; names are NUL-terminated
    // strings inside the model's name buffer (null for an unnamed camera).
    unsafe {
        (0..(*m).ncam)
            .map(|i| {
                let p: *const c_char = api.mj_id2name(m, ffi::mjOBJ_CAMERA as c_int, i);
                if p.is_null() {
                    format!("camera{i}")
                } else {
                    CStr::from_ptr(p).to_string_lossy().into_owned()
                }
            })
            .collect()
    }
}

/// Whether a headless OpenGL context can be made here (EGL and Mesa's software driver load).
/// `Err` says what is missing and which Debian packages to install.
pub fn check_gl() -> Result<()> {
    egl().map(|_| ())
}
