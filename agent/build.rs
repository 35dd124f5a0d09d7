//! Embeds an rpath to libtorch's `lib/` directory so that `million` and its tests run without
//! `LD_LIBRARY_PATH`. torch-sys (`links = "tch"`) exports the directory it linked against as
//! `DEP_TCH_LIBTORCH_LIB`; that is the one place that knows which libtorch was used (a
//! `LIBTORCH` install or the Python wheel via `LIBTORCH_USE_PYTORCH`).

fn main() {
    println!("cargo:rerun-if-env-changed=DEP_TCH_LIBTORCH_LIB");
    match std::env::var("DEP_TCH_LIBTORCH_LIB") {
        Ok(dir) if !dir.is_empty() => {
            println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
        }
        _ => println!(
            "cargo:warning=torch-sys did not report its libtorch lib dir; set LD_LIBRARY_PATH to run million"
        ),
    }
}
