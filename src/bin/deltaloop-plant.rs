//! `deltaloop-plant`: the plant process, started by `deltaloop run`.
fn main() -> std::process::ExitCode {
    deltaloop_plant::process::main()
}
