fn main() {
    eprintln!("raytile: not built yet");
    std::process::exit(1)
}
