//! maturin's sdist stores every file with mode 0644, so a build from it would find the
//! wheel's linker (scripts/wheel-linker, rustc-args in pyproject.toml) not executable.

fn main() {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let script =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/wheel-linker");
        println!("cargo:rerun-if-changed={}", script.display());
        if let Ok(meta) = std::fs::metadata(&script) {
            let mode = meta.permissions().mode();
            if mode & 0o111 == 0 {
                // A read-only tree keeps the mode; rustc's error then names the script.
                let _ = std::fs::set_permissions(
                    &script,
                    std::fs::Permissions::from_mode(mode | 0o111),
                );
            }
        }
    }
}
