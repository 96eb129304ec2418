// Which OpenEXR decoder OpenImageIO opens a file with, in one place for the EXRs io reads (passes
// in io/pass_reader.cpp, the idle compression's read-back in io/image_writer.cpp): OpenEXR's Core C
// library where io::core_decodes allows it, the C++ library elsewhere (docs/api.md, "Pass files:
// bounded before decoding").
#pragma once

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <memory>

namespace proden::io::detail {

// An unopened OpenEXR input of OpenImageIO: the Core-library one when `core`, the C++-library one
// otherwise; reading through `proxy` when given. OIIO chooses between them by a process-wide
// attribute read when an input is created, so io creates its EXR inputs here, under one lock, and
// leaves the attribute at its default (the C++ library) in between.
std::unique_ptr<OIIO::ImageInput> create_exr_input(bool core,
                                                   OIIO::Filesystem::IOProxy* proxy = nullptr);

}  // namespace proden::io::detail
