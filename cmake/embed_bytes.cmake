# Turns a binary file into a C++ source defining a byte array (the learned mixer's weights are
# built into the binary). Usage: cmake -DIN=file -DOUT=file.cpp -DSYMBOL=name -P embed_bytes.cmake
file(READ "${IN}" hex HEX)
string(LENGTH "${hex}" hex_len)
math(EXPR size "${hex_len} / 2")
string(REGEX REPLACE "([0-9a-f][0-9a-f])" "0x\\1," body "${hex}")
get_filename_component(name "${IN}" NAME)
file(WRITE "${OUT}.tmp"
  "// Generated from ${name} by cmake/embed_bytes.cmake; do not edit.\n"
  "#include <cstddef>\n"
  "extern const unsigned char ${SYMBOL}[];\n"
  "extern const std::size_t ${SYMBOL}_size;\n"
  "extern const char ${SYMBOL}_name[];\n"
  "alignas(16) const unsigned char ${SYMBOL}[] = {${body}};\n"
  "const std::size_t ${SYMBOL}_size = ${size};\n"
  "const char ${SYMBOL}_name[] = \"${name}\";\n")
file(RENAME "${OUT}.tmp" "${OUT}")
