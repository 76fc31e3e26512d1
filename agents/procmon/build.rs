//! Compiles the C BPF program `bpf/procmon.bpf.c` with clang (`-target bpfel`/`bpfeb`,
//! `-O2 -g`) into `$OUT_DIR/procmon.bpf.o`, which `src/ebpf.rs` embeds.
//!
//! clang is required: a missing or failing clang stops the build with a message
//! saying what to install. To build on a machine without clang on purpose, set
//! `CONFIGBOT_PROCMON_NO_BPF=1`: the crate is then compiled with
//! `--cfg procmon_no_bpf`, the eBPF monitor reports "built without BPF" at start,
//! and the proc connector / /proc scan fallbacks still work.
//! `CLANG` overrides the compiler path.

use std::env;
use std::path::PathBuf;
use std::process::Command;

const SOURCE: &str = "bpf/procmon.bpf.c";

fn main() {
    println!("cargo::rustc-check-cfg=cfg(procmon_no_bpf)");
    println!("cargo::rerun-if-changed={SOURCE}");
    println!("cargo::rerun-if-env-changed=CLANG");
    println!("cargo::rerun-if-env-changed=CONFIGBOT_PROCMON_NO_BPF");

    if env::var("CONFIGBOT_PROCMON_NO_BPF").is_ok_and(|v| v == "1") {
        println!(
            "cargo::warning=CONFIGBOT_PROCMON_NO_BPF=1: building configbot-procmon without the eBPF monitor"
        );
        println!("cargo::rustc-cfg=procmon_no_bpf");
        return;
    }

    let out_dir = PathBuf::from(env::var("OUT_DIR").unwrap_or_else(|_| fail("OUT_DIR is not set")));
    let object = out_dir.join("procmon.bpf.o");
    let clang = env::var("CLANG").unwrap_or_else(|_| "clang".to_owned());
    let endian = env::var("CARGO_CFG_TARGET_ENDIAN").unwrap_or_else(|_| "little".to_owned());
    let target = if endian == "big" { "bpfeb" } else { "bpfel" };

    let mut cmd = Command::new(&clang);
    cmd.args(["-target", target, "-O2", "-g", "-Wall", "-Werror"]);
    // <linux/types.h> includes <asm/types.h>, which Debian keeps under the multiarch dir.
    if let Some(multiarch) = multiarch_include() {
        cmd.arg(format!("-I{multiarch}"));
    }
    cmd.args(["-c", SOURCE, "-o"]).arg(&object);

    let output = match cmd.output() {
        Ok(output) => output,
        Err(err) => fail(&format!(
            "cannot run `{clang}` ({err}). The eBPF process monitor is compiled with clang: \
             install it with `apt-get install -y clang libbpf-dev` (or set CLANG=/path/to/clang), \
             or build without eBPF with CONFIGBOT_PROCMON_NO_BPF=1"
        )),
    };
    if !output.status.success() {
        fail(&format!(
            "`{clang} -target {target}` failed on {SOURCE} ({}). Are the headers installed \
             (`apt-get install -y libbpf-dev linux-libc-dev`)?\n{}",
            output.status,
            String::from_utf8_lossy(&output.stderr)
        ));
    }
}

/// `/usr/include/<triple>` for the target, if it exists (Debian/Ubuntu multiarch).
fn multiarch_include() -> Option<String> {
    let arch = env::var("CARGO_CFG_TARGET_ARCH").ok()?;
    let triple = match arch.as_str() {
        "x86_64" => "x86_64-linux-gnu",
        "aarch64" => "aarch64-linux-gnu",
        "arm" => "arm-linux-gnueabihf",
        "riscv64" => "riscv64-linux-gnu",
        other => return Some(format!("/usr/include/{other}-linux-gnu")),
    };
    let dir = format!("/usr/include/{triple}");
    std::path::Path::new(&dir).is_dir().then_some(dir)
}

fn fail(message: &str) -> ! {
    eprintln!("error: configbot-procmon build: {message}");
    std::process::exit(1)
}
