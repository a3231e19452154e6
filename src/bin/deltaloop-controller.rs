//! `deltaloop-controller`: the controller process, started by `deltaloop run`.
fn main() -> std::process::ExitCode {
    deltaloop_controller::process::main()
}
