//! `raytile`: render locally, submit to a farm, or run a local cluster.

use clap::{Parser, Subcommand};

mod cluster;
mod submit;

/// raytile: a distributed path tracer.
#[derive(Parser, Debug)]
#[command(version)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Upload a scene to a coordinator, submit a job, and optionally wait for the image.
    Submit(submit::SubmitArgs),
    /// Run a coordinator and local workers in this process (optionally render one scene).
    Cluster(cluster::ClusterArgs),
}

fn main() {
    let cli = Cli::parse();
    let r = match cli.command {
        Command::Submit(a) => submit::run(a),
        Command::Cluster(a) => cluster::run(a),
    };
    if let Err(e) = r {
        eprintln!("raytile: {e:#}");
        std::process::exit(1);
    }
}
