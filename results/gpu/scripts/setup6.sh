# Unpacks the carried software into /tmp/dev (ffmpeg came in the first call) and exports its paths.
D=/tmp/dev; mkdir -p $D/lib
x() { python3 -c "import tarfile,sys; tarfile.open(sys.argv[1]).extractall(sys.argv[2], filter='tar')" "$1" "$2"; }
[ -f .devcarry/site.tar.xz ] && x .devcarry/site.tar.xz $D
[ -f .devcarry/llvm.tar.xz ] && x .devcarry/llvm.tar.xz $D/lib
export PYTHONPATH=$D/site LD_LIBRARY_PATH=$D/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
export DRJIT_LIBLLVM_PATH=$D/lib/libLLVM.so.19.1 IMAGEIO_FFMPEG_EXE=$D/ffmpeg PYTHONUNBUFFERED=1 PYTHONDONTWRITEBYTECODE=1
PY=python3
ls -la $D $D/lib | head -20
