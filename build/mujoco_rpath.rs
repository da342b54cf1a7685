//! Embeds an rpath to MuJoCo's directory (`MUJOCO_DYNAMIC_LINK_DIR`, set by
//! .cargo/config.toml) into the binaries and tests of every package that names this file as its
//! `build` script (those that link MuJoCo), so they run without
//! LD_LIBRARY_PATH.
fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
