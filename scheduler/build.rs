//! With the `mpi` feature: compiles the MPI shim (`src/transport/mpi_shim.c`) with the MPI compiler
//! wrapper (`$MPICC`, else `mpicc`) and links the MPI library it names (`-showme:link` for Open MPI,
//! `-show` for MPICH). Without the feature: nothing (the default build needs no MPI).

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    #[cfg(feature = "mpi")]
    build_mpi_shim();
}

#[cfg(feature = "mpi")]
fn build_mpi_shim() {
    println!("cargo:rerun-if-changed=src/transport/mpi_shim.c");
    println!("cargo:rerun-if-env-changed=MPICC");
    let mpicc = std::env::var("MPICC").unwrap_or_else(|_| "mpicc".to_string());
    let link = ["-showme:link", "-show"]
        .iter()
        .find_map(|flag| {
            let out = std::process::Command::new(&mpicc).arg(flag).output().ok()?;
            out.status
                .success()
                .then(|| String::from_utf8_lossy(&out.stdout).to_string())
        })
        .unwrap_or_else(|| {
            panic!(
                "the `mpi` feature needs an MPI compiler wrapper: `{mpicc}` did not run (install Open MPI: \
                 apt-get install libopenmpi-dev openmpi-bin, or set MPICC)"
            )
        });
    cc::Build::new()
        .compiler(&mpicc)
        .file("src/transport/mpi_shim.c")
        .warnings(true)
        .compile("blockflow_mpi_shim");
    for word in link.split_whitespace() {
        if let Some(dir) = word.strip_prefix("-L") {
            println!("cargo:rustc-link-search=native={dir}");
        } else if let Some(lib) = word.strip_prefix("-l") {
            println!("cargo:rustc-link-lib={lib}");
        } else if let Some(arg) = word.strip_prefix("-Wl,") {
            println!("cargo:rustc-link-arg=-Wl,{arg}");
        }
    }
}
