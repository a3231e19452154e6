//! Writes the pkg-config files of the C ABI next to the built library (the profile's folder,
//! `target/<profile>/`, and its `deps/`, where the tests find the library): how a C program
//! compiles and links against it.
//!
//! - `deltaloop_peer.pc`: the shared library, `-ldeltaloop_peer` with an rpath to its folder;
//! - `deltaloop_peer-static.pc`: the static one, `libdeltaloop_peer.a` and the system libraries
//!   Rust's standard library needs (what `rustc --print native-static-libs` says on Linux; the
//!   static-link test fails if one is missing).
//!
//! `libdir` is `${pcfiledir}`: a file found through `PKG_CONFIG_PATH=target/release` names the
//! library beside it, wherever the checkout is.

use std::path::{Path, PathBuf};

/// The system libraries the static library needs (Linux, glibc).
const NATIVE_STATIC_LIBS: &str = "-lgcc_s -lutil -lrt -lpthread -lm -ldl -lc";

fn main() {
    println!("cargo::rerun-if-changed=build.rs");
    let (Some(out), Some(manifest)) = (
        std::env::var_os("OUT_DIR").map(PathBuf::from),
        std::env::var_os("CARGO_MANIFEST_DIR").map(PathBuf::from),
    ) else {
        return;
    };
    // OUT_DIR is target/<profile>/build/<package>-<hash>/out.
    let Some(profile) = out.ancestors().nth(3) else {
        return;
    };
    let include = manifest.join("include");
    let version = std::env::var("CARGO_PKG_VERSION").unwrap_or_default();
    let head = |name: &str, what: &str| {
        format!(
            "libdir=${{pcfiledir}}\nincludedir={}\n\nName: {name}\nDescription: deltaloop's C ABI ({what}): a controller or a plant in C joins a deltaloop run\nVersion: {version}\nCflags: -I${{includedir}}\n",
            include.display()
        )
    };
    let shared = format!(
        "{}Libs: -L${{libdir}} -Wl,-rpath,${{libdir}} -ldeltaloop_peer\nLibs.private: {NATIVE_STATIC_LIBS}\n",
        head("deltaloop_peer", "shared library")
    );
    let static_ = format!(
        "{}Libs: ${{libdir}}/libdeltaloop_peer.a {NATIVE_STATIC_LIBS}\n",
        head("deltaloop_peer-static", "static library")
    );
    for dir in [profile.to_path_buf(), profile.join("deps")] {
        write(&dir, "deltaloop_peer.pc", &shared);
        write(&dir, "deltaloop_peer-static.pc", &static_);
    }
}

/// Writes `text` to `dir/name` unless it is there already (a build must not fail over it: the
/// library builds without the file, and the test that links through it says what is missing).
fn write(dir: &Path, name: &str, text: &str) {
    let path = dir.join(name);
    if std::fs::read_to_string(&path).is_ok_and(|t| t == text) {
        return;
    }
    if let Err(e) = std::fs::create_dir_all(dir).and_then(|()| std::fs::write(&path, text)) {
        println!("cargo::warning=cannot write {}: {e}", path.display());
    }
}
