//! What the far host runs: the process of the remote side, the built-in one or the user's.

use deltaloop_config::RemoteSide;

/// The built-in program of `side`, looked for next to `deltaloop-bridge`.
pub fn far_program(side: RemoteSide) -> &'static str {
    match side {
        RemoteSide::Controller => "deltaloop-controller",
        RemoteSide::Plant => "deltaloop-plant",
    }
}

/// The user's command for `side` (`--controller-cmd` or `--plant-cmd` of `join`, split at
/// whitespace), or None for the built-in program; one line naming the flag if the command is
/// the other side's or empty.
pub fn far_command(
    side: RemoteSide,
    controller_cmd: Option<&str>,
    plant_cmd: Option<&str>,
) -> Result<Option<Vec<String>>, String> {
    let (mine, flag) = match (side, controller_cmd, plant_cmd) {
        (RemoteSide::Plant, Some(_), _) => return Err(
            "--controller-cmd with --role plant: the controller runs on the other host (give it to `deltaloop run --controller-cmd` there); allowed here: --plant-cmd".into()
        ),
        (RemoteSide::Controller, _, Some(_)) => return Err(
            "--plant-cmd with --role controller: the plant runs on the other host (give it to `deltaloop run --plant-cmd` there); allowed here: --controller-cmd".into()
        ),
        (RemoteSide::Plant, None, c) => (c, "--plant-cmd"),
        (RemoteSide::Controller, c, None) => (c, "--controller-cmd"),
    };
    let Some(c) = mine else { return Ok(None) };
    let cmd: Vec<String> = c.split_whitespace().map(str::to_string).collect();
    if cmd.is_empty() {
        return Err(format!("{flag} is empty: give a program and its arguments"));
    }
    Ok(Some(cmd))
}
