fn main() {
    eprintln!("raytile-coordinator: not built yet (see the farm issue)");
    std::process::exit(1)
}
