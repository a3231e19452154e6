//! `deltaloop-controller`: the controller process, started by `deltaloop run`; across two hosts
//! over the link's socket its bridge hands on at START, else over iceoryx2.
fn main() -> std::process::ExitCode {
    deltaloop_controller::process::main(deltaloop_link::Handoff::default())
}
