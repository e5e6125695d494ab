// intel_tex_2's ISPC kernels reference the C++ runtime (`__gxx_personality_v0`);
// link libstdc++ into every binary that uses this crate.
fn main() {
    println!("cargo:rustc-link-lib=dylib=stdc++");
}
