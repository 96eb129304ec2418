// Hand-built OpenEXR files, byte by byte (OpenEXR "File Layout" document), for tests that need
// headers no writer would produce: oversized attributes, absurd data windows, odd channel names.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace proden::test {

struct ExrAttribute {
  std::string name, type;
  std::vector<std::uint8_t> value;
  std::int64_t declared_size = -1;  // written instead of value.size() when >= 0
};

struct ExrSpec {
  int width = 4, height = 3;  // data and display window (0,0)-(w-1,h-1)
  int declared_width = 0;     // > 0: the windows declare this size instead
  int declared_height = 0;
  std::vector<std::string> channels = {"B", "G", "R"};  // written in this order (EXR sorts them)
  std::vector<ExrAttribute> extra;                      // appended after the required attributes
  bool pixels = true;   // write the offset table and uncompressed float scanlines
  float value = 0.25f;  // every sample
};

// An uncompressed single-part scanline EXR with FLOAT channels.
std::vector<std::uint8_t> exr_bytes(const ExrSpec& spec);

// A string attribute (type "string").
ExrAttribute string_attribute(const std::string& name, const std::string& value);

void write_bytes(const std::string& path, const std::vector<std::uint8_t>& bytes);

}  // namespace proden::test
