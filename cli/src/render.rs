//! `raytile render`: one scene, one machine, one image.

use anyhow::{anyhow, Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use raytile_core::film::{self, OutputOptions, ToneMap};
use raytile_core::scene::files::SceneFiles;
use raytile_core::scene::gltf::{no_light_warning, NO_LIGHT_WARNING};
use raytile_core::scene::job::pick_camera;
use raytile_core::{load_scene, RenderJob, RenderOverrides, RenderProgress, Scene, SettingsError};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

/// A settings error as the command line says it: the field as its flag (`--max-depth`).
pub fn flag_error(e: SettingsError) -> anyhow::Error {
    anyhow!("--{}: {}", e.field.replace('_', "-"), e.message)
}

/// Arguments of `raytile render`.
#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Scene file: .json (raytile format), .gltf or .glb; or a folder with one scene file at
    /// its top.
    pub scene: PathBuf,
    /// Output image: .png, .exr or .hdr.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Settings that differ from the scene's own.
    #[command(flatten)]
    pub overrides: RenderOverrides,
    /// Worker threads (default: all cores; at most 1024).
    #[arg(long, value_parser = crate::threads_flag(1))]
    pub threads: Option<usize>,
    /// How a PNG is made of the linear image.
    #[command(flatten)]
    pub look: LookArgs,
}

/// `--exposure` and `--tonemap`: how a PNG is made of the linear image (`raytile render`
/// applies them itself; `submit` and `cluster` ask the coordinator for such a PNG).
#[derive(Args, Debug, Clone, Copy, Default)]
pub struct LookArgs {
    /// Exposure in stops for PNG output (-64 to 64).
    #[arg(long, default_value_t = 0.0, value_parser = crate::exposure_flag, allow_hyphen_values = true)]
    pub exposure: f32,
    /// Tone map for PNG output: clamp or aces.
    #[arg(long, default_value = "clamp")]
    pub tonemap: ToneMap,
}

impl LookArgs {
    /// The output options.
    pub fn options(self) -> OutputOptions {
        OutputOptions {
            exposure: self.exposure,
            tonemap: self.tonemap,
        }
    }

    /// Warns when the flags were given for an image they do not shape (not a PNG).
    pub fn warn_unless_png(self, format: film::ImageFormat, output: &std::path::Path) {
        if format != film::ImageFormat::Png && self.options() != OutputOptions::default() {
            eprintln!(
                "raytile: warning: --exposure and --tonemap shape PNG output only; {} keeps \
                 the linear radiance",
                output.display()
            );
        }
    }

    /// Warns when a render with an alpha channel goes to a format without one (Radiance).
    pub fn warn_if_alpha_lost(alpha: bool, format: film::ImageFormat, output: &std::path::Path) {
        if alpha && format == film::ImageFormat::Hdr {
            eprintln!(
                "raytile: warning: Radiance .hdr files have no alpha channel: {} gets the \
                 colour premultiplied by alpha (the image over black); write .exr or .png to \
                 keep it",
                output.display()
            );
        }
    }

    /// The image request's query parameters for them (none for the defaults or an image
    /// that is not a PNG).
    pub fn query(self, format: film::ImageFormat) -> Vec<(&'static str, String)> {
        if format != film::ImageFormat::Png || self.options() == OutputOptions::default() {
            return Vec::new();
        }
        let curve = match self.tonemap {
            ToneMap::Clamp => "clamp",
            ToneMap::Aces => "aces",
        };
        vec![
            ("exposure", self.exposure.to_string()),
            ("tonemap", curve.to_string()),
        ]
    }
}

struct Progress {
    bar: Option<ProgressBar>,
    done: AtomicU64,
    total: u64,
    last_line: Mutex<u64>,
}

impl RenderProgress for Progress {
    fn tile_done(&self, samples: u64) {
        let done = self.done.fetch_add(samples, Ordering::Relaxed) + samples;
        match &self.bar {
            Some(b) => b.set_position(done),
            None => {
                // Not a terminal: a plain line every 10%.
                let pct = done * 10 / self.total.max(1);
                let mut last = self.last_line.lock().unwrap_or_else(|e| e.into_inner());
                if pct > *last {
                    *last = pct;
                    eprintln!("raytile: {}% rendered", pct * 10);
                }
            }
        }
    }
}

/// A job's refusal as the command line says it: "render setting environment: ..." names its
/// flag (`--environment: ...`); other errors (the scene's, a map file's) stay as they are.
fn setting_as_flag(e: raytile_core::SceneError) -> anyhow::Error {
    let text = e.to_string();
    let flag = text
        .strip_prefix("render setting ")
        .and_then(|rest| rest.split_once(": "))
        .filter(|(field, _)| RenderOverrides::FIELDS.contains(field));
    match flag {
        Some((field, message)) => anyhow!("--{}: {message}", field.replace('_', "-")),
        None => e.into(),
    }
}

/// Runs `raytile render`.
pub fn run(args: RenderArgs) -> Result<()> {
    let start = Instant::now();
    let format = film::ImageFormat::from_path(&args.output)?;
    film::check_writable(&args.output)?;
    args.look.warn_unless_png(format, &args.output);
    let desc = if args.scene.is_dir() {
        load_scene(&crate::submit::scene_in_folder(&args.scene)?)?
    } else {
        load_scene(&args.scene)?
    };
    let settings = desc.render.resolve(&args.overrides).map_err(flag_error)?;
    if args.overrides.camera.is_some() {
        // A camera the scene does not have is the flag's error, said before the scene is built.
        let names: Vec<&str> = desc.cameras.iter().map(|c| c.name.as_str()).collect();
        pick_camera(&names, settings.camera.as_deref()).map_err(flag_error)?;
    }
    // What sppm cannot render, said before the scene is built, naming the flag.
    desc.sppm_facts()
        .check(&settings)
        .map_err(|e| anyhow!("--integrator: {e}"))?;
    LookArgs::warn_if_alpha_lost(settings.alpha, format, &args.output);
    for w in &desc.warnings {
        // The default light's warning says what this render does in its place.
        if w == NO_LIGHT_WARNING {
            eprintln!("raytile: warning: {}", no_light_warning(&settings));
        } else {
            eprintln!("raytile: warning: {w}");
        }
    }
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(t) = args.threads {
        pool = pool.num_threads(t);
    }
    let pool = pool.build().context("starting worker threads")?;
    let loaded = start.elapsed().as_secs_f64();
    let scene = pool.install(move || Scene::build_owned(desc))?;
    let built = start.elapsed().as_secs_f64() - loaded;
    // An environment map given on the command line is read as given (relative to the
    // current folder).
    let job = RenderJob::with_files(&scene, &settings, &SceneFiles::trusted(), Path::new("."))
        .map_err(setting_as_flag)?;
    let total = settings.width as u64 * settings.height as u64 * settings.spp as u64;
    let bar = std::io::stderr().is_terminal().then(|| {
        let b = ProgressBar::new(total);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {wide_bar} {percent}% eta {eta}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        b
    });
    let progress = Progress {
        bar,
        done: AtomicU64::new(0),
        total,
        last_line: Mutex::new(0),
    };
    // Where the time to the first pixel goes, and what the scene holds (`scripts/mesh-memory.sh`
    // reads this line).
    eprintln!(
        "raytile: scene loaded in {loaded:.3} s, built in {built:.3} s ({} triangles, {:.1} MB); rendering from {:.3} s",
        scene.stats.flattened_triangles + scene.stats.instanced_triangles,
        scene.memory_bytes() as f64 / 1e6,
        start.elapsed().as_secs_f64()
    );
    let render_start = Instant::now();
    let film = pool.install(|| raytile_core::render(&scene, &job, &progress));
    let secs = render_start.elapsed().as_secs_f64();
    if let Some(b) = &progress.bar {
        b.finish_and_clear();
    }
    film::save(
        &film,
        &args.output,
        &args.look.options(),
        &film::Metadata::of_render(&settings, &film),
    )?;
    if film.bad_samples > 0 {
        eprintln!(
            "raytile: warning: {} NaN, infinite or too large samples were dropped",
            film.bad_samples
        );
    }
    eprintln!(
        "raytile: {}x{}, {} spp, {} integrator, {:.3} s render ({:.3} s total), {:.3} Msamples/s -> {}",
        settings.width,
        settings.height,
        settings.spp,
        settings.integrator.name(),
        secs,
        start.elapsed().as_secs_f64(),
        total as f64 / secs.max(1e-9) / 1e6,
        args.output.display()
    );
    Ok(())
}
