//! `raytile`: render a scene locally, submit it to a farm, or run a local cluster.

mod bench;
mod cluster;
mod render;
mod submit;

use clap::{Parser, Subcommand};

// A build for newer CPUs stops before `main` on a CPU without them, with a message.
raytile_core::cpu_gate!();

/// Large blocks (a big scene's arrays) in mappings of their own: less memory held while a
/// scene loads and builds (see `raytile_core::alloc`).
#[global_allocator]
static ALLOC: raytile_core::alloc::LargeBlocks = raytile_core::alloc::LargeBlocks;

/// raytile: a distributed path tracer.
#[derive(Parser)]
#[command(name = "raytile", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene on this machine.
    Render(render::RenderArgs),
    /// Measure samples/s, ray throughput and BVH build times.
    Bench(bench::BenchArgs),
    /// Upload a scene to a coordinator, submit a job, and optionally wait for the image.
    Submit(submit::SubmitArgs),
    /// Run a coordinator and local workers in this process (optionally render one scene).
    Cluster(cluster::ClusterArgs),
}

/// The parser of a `--threads` flag: `min` to [`raytile_worker::MAX_THREADS`].
fn threads_flag(min: u64) -> clap::builder::RangedU64ValueParser<usize> {
    clap::builder::RangedU64ValueParser::<usize>::new()
        .range(min..=raytile_worker::MAX_THREADS as u64)
}

/// `--exposure`: a finite number of stops, at most 64 either way (2^64 keeps every value a
/// film holds finite).
fn exposure_flag(s: &str) -> Result<f32, String> {
    let x: f32 = s
        .parse()
        .map_err(|_| format!("not a number of stops: '{s}'"))?;
    if x.is_finite() && x.abs() <= 64.0 {
        Ok(x)
    } else {
        Err(format!(
            "must be a finite number of stops from -64 to 64, got {s}"
        ))
    }
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => render::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Submit(args) => submit::run(args),
        Command::Cluster(args) => cluster::run(args),
    };
    if let Err(e) = result {
        eprintln!("raytile: {e:#}");
        std::process::exit(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use raytile_core::{IntegratorKind, RenderOverrides};

    fn overrides(args: &[&str]) -> RenderOverrides {
        let cli = Cli::try_parse_from(args).unwrap();
        match cli.command {
            Command::Render(a) => a.overrides,
            Command::Submit(a) => a.job.overrides,
            Command::Cluster(a) => a.job.overrides,
            Command::Bench(_) => unreachable!(),
        }
    }

    #[test]
    fn render_submit_and_cluster_read_the_same_settings_flags() {
        let flags = [
            "--width",
            "64",
            "--height",
            "32",
            "--spp",
            "8",
            "--max-depth",
            "3",
            "--integrator",
            "ao",
            "--seed",
            "7",
            "--camera",
            "side",
            "--filter",
            "gaussian",
            "--tile-size",
            "16",
            "--passes",
            "2",
            "--no-default-light",
            "--environment",
            "sky.hdr",
            "--environment-rotation",
            "-90",
            "--environment-strength",
            "2.5",
            "--alpha",
        ];
        let want = RenderOverrides {
            width: Some(64),
            height: Some(32),
            spp: Some(8),
            max_depth: Some(3),
            integrator: Some(IntegratorKind::Ao),
            seed: Some(7),
            camera: Some("side".into()),
            filter: Some(raytile_core::settings::FilterKind::Gaussian),
            tile_size: Some(16),
            passes: Some(2),
            default_light: Some(false),
            environment: Some(raytile_core::EnvironmentChoice::Map("sky.hdr".into())),
            environment_rotation: Some(-90.0),
            environment_strength: Some(2.5),
            alpha: Some(true),
        };
        for command in [
            &["raytile", "render", "s.json", "-o", "x.png"][..],
            &["raytile", "submit", "s.json"],
            &["raytile", "cluster", "--render", "s.json"],
        ] {
            let args: Vec<&str> = command.iter().chain(&flags).copied().collect();
            assert_eq!(overrides(&args), want, "{command:?}");
            assert_eq!(
                overrides(command),
                RenderOverrides::default(),
                "{command:?}"
            );
            // `--alpha=false` turns off a scene's own alpha channel.
            let args: Vec<&str> = command.iter().chain(&["--alpha=false"]).copied().collect();
            assert_eq!(overrides(&args).alpha, Some(false), "{command:?}");
        }
    }

    #[test]
    fn environment_values_parse_or_are_refused_by_the_parser() {
        for (value, want) in [
            ("none", raytile_core::EnvironmentChoice::None),
            (
                "0.5,0.5,1",
                raytile_core::EnvironmentChoice::Constant([0.5, 0.5, 1.0]),
            ),
        ] {
            let o = overrides(&["raytile", "submit", "s.json", "--environment", value]);
            assert_eq!(o.environment, Some(want));
        }
        let e = Cli::try_parse_from([
            "raytile",
            "render",
            "s.json",
            "-o",
            "x.png",
            "--environment",
            "sky.png",
        ])
        .err()
        .unwrap()
        .to_string();
        assert!(e.contains("--environment") && e.contains(".hdr"), "{e}");
    }

    #[test]
    fn unknown_names_are_refused_by_the_parser() {
        let e = Cli::try_parse_from(["raytile", "submit", "s.json", "--integrator", "magic"])
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("--integrator") && e.contains("unknown integrator 'magic'"),
            "{e}"
        );
    }
}
