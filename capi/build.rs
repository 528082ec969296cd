//! libussrt.so carries its soname, so programs linked against it load the ABI they were built
//! for (`libussrt.so.0`; install.sh installs the symbolic links).
fn main() {
    println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,libussrt.so.0");
}
