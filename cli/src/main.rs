//! The `configbot` command. The commands live in the library (`configbot`)
//! so the end-to-end tests build and run exactly this program.

fn main() -> std::process::ExitCode {
    configbot::main()
}
