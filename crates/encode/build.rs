// intel_tex_2's ISPC kernels reference the C++ runtime (`__gxx_personality_v0`
// and friends): link the one the target's toolchain uses. MSVC links its
// runtime by itself.
fn main() {
    let target = std::env::var("TARGET").unwrap_or_default();
    let lib = if target.contains("apple") || target.contains("freebsd") || target.contains("openbsd") {
        Some("c++")
    } else if target.contains("msvc") {
        None
    } else if target.contains("android") {
        Some("c++_shared")
    } else {
        // linux-gnu, linux-musl, windows-gnu (MinGW) and other GNU toolchains.
        Some("stdc++")
    };
    if let Some(lib) = lib {
        println!("cargo:rustc-link-lib=dylib={lib}");
    }
    println!("cargo:rerun-if-changed=build.rs");
}
