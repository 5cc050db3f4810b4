//! `raytile`: render a scene locally, submit it to a farm, or run a local cluster.

mod bench;
mod cluster;
mod render;
mod submit;

use clap::{Parser, Subcommand};

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
