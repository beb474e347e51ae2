// Parses each ros2msg schema given on stdin ([{"name": ..., "text": ...}, ...]) with Foxglove's
// own parser (@foxglove/rosmsg, as Foxglove Studio does for ros2msg schemas) and prints, per
// schema, the fields of its first definition ([{"name", "type"}]) or the parser's error.
const { parse } = require("@foxglove/rosmsg");

let input = "";
process.stdin.on("data", (chunk) => (input += chunk));
process.stdin.on("end", () => {
  const out = JSON.parse(input).map(({ name, text }) => {
    try {
      const [first] = parse(text, { ros2: true });
      return { name, fields: first.definitions.filter((d) => !d.isConstant).map((d) => ({ name: d.name, type: d.type })) };
    } catch (err) {
      return { name, error: String(err.message || err) };
    }
  });
  process.stdout.write(JSON.stringify(out));
});
