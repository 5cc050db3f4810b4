//! `raytile`: render a scene locally, submit it to a farm, or run a local cluster.

mod bench;
mod render;

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
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => render::run(args),
        Command::Bench(args) => bench::run(args),
    };
    if let Err(e) = result {
        eprintln!("raytile: {e:#}");
        std::process::exit(1);
    }
}
