// Runs a cam program's Structured Text on pyplcopen's ST virtual machine and axis model
// (built from pyplcopen's sdist by tests/plc_vm.py; no source of it is in this repository).
//
// usage: cam_vm PROGRAM.st NAME TABLE.csv PERIOD_NS CYCLES MASTER_END
// The program NAME is compiled and loaded with the task period PERIOD_NS; its axes
// "Master" and "Slave" are bound to two powered axis models and the cam "ClampCam" to the
// table (master,slave per line; at most 64 points, linear). The master is a virtual axis
// moved by this host from 0 to MASTER_END in CYCLES equal steps, one per scan. Prints one
// line per scan: cycle, master command position, slave command position, InSync, Error.
#include "axis/group.h"
#include "axis/state.h"
#include "rt/error_text.h"
#include "st/st.h"

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

using namespace plcopen::core;

int main(int argc, char **argv)
{
    if(argc != 7) {
        std::fprintf(stderr, "usage: cam_vm PROGRAM.st NAME TABLE.csv PERIOD_NS CYCLES MASTER_END\n");
        return 2;
    }
    std::ifstream source_file(argv[1]);
    std::stringstream source;
    source << source_file.rdbuf();
    std::vector<exec::CamPoint> table;
    std::ifstream rows(argv[3]);
    for(std::string line; std::getline(rows, line);) {
        if(line.empty()) continue;
        exec::CamPoint point;
        if(std::sscanf(line.c_str(), "%lf,%lf", &point.master, &point.slave) != 2) {
            std::fprintf(stderr, "cam_vm: bad table row %s\n", line.c_str());
            return 2;
        }
        table.push_back(point);
    }
    const std::int64_t period_ns = std::atoll(argv[4]);
    const long cycles = std::atol(argv[5]);
    const double master_end = std::atof(argv[6]);

    const st::CompileResult compiled = st::compile(source.str());
    if(!compiled.ok) {
        for(const st::Diagnostic &d : compiled.diagnostics)
            std::fprintf(stderr, "cam_vm: line %d column %d: %s %s\n", d.line, d.column,
                         st::to_string(d.code), d.message.c_str());
        return 3;
    }
    std::vector<std::uint64_t> storage((compiled.program.required_bytes() + 7U) / 8U + 1U);
    st::Instance vm;
    axis::AxisModel master, slave;
    axis::MotionLimits limits;  // the slave follows the cam: no limit of the model's own
    limits.max_velocity = limits.max_acceleration = limits.max_deceleration = 1e12;
    limits.max_jerk = 1e18;
    if(slave.configure_limits(limits) != rt::ErrorCode::ok ||
       master.configure_limits(limits) != rt::ErrorCode::ok) {
        std::fprintf(stderr, "cam_vm: axis limits refused\n");
        return 4;
    }
    master.set_power(true);
    slave.set_power(true);
    axis::AxisGroup group;  // MC_CamTableSelect and MC_CamIn couple axes of one group
    group.add_axis(master);
    group.add_axis(slave);
    group.enable();
    const rt::ErrorCode loaded =
        vm.load(compiled.program, argv[2], reinterpret_cast<unsigned char *>(storage.data()),
                storage.size() * sizeof(storage[0]), period_ns);
    if(loaded != rt::ErrorCode::ok) {
        std::fprintf(stderr, "cam_vm: load failed: %s\n", rt::to_string(loaded));
        return 4;
    }
    const st::BindingError bound[] = {
        vm.bind_axis("Master", &master), vm.bind_axis("Slave", &slave),
        vm.bind_cam_table("ClampCam", table.data(), table.size(), false)};
    for(std::size_t i = 0; i < 3; ++i) {
        if(bound[i] != st::BindingError::ok) {
            std::fprintf(stderr, "cam_vm: binding %zu failed (%d)\n", i,
                         static_cast<int>(bound[i]));
            return 4;
        }
    }
    const int in_sync = vm.find("InSync"), error = vm.find("Error");
    if(in_sync < 0 || error < 0) {
        std::fprintf(stderr, "cam_vm: InSync or Error not found\n");
        return 4;
    }
    for(long k = 0; k <= cycles; ++k) {
        const double position = master_end * static_cast<double>(k) / static_cast<double>(cycles);
        if(master.set_position(position) != rt::ErrorCode::ok) {
            std::fprintf(stderr, "cam_vm: master position refused at %ld\n", k);
            return 5;
        }
        const st::ScanError scanned = vm.scan(1 << 20);
        if(scanned != st::ScanError::ok) {
            std::fprintf(stderr, "cam_vm: scan %ld failed: %s\n", k, st::to_string(scanned));
            return 5;
        }
        master.cycle();
        slave.cycle();
        std::printf("%ld,%.17g,%.17g,%d,%d\n", k, master.snapshot().command_position,
                    slave.snapshot().command_position,
                    static_cast<int>(vm.value_bool(static_cast<std::size_t>(in_sync))),
                    static_cast<int>(vm.value_bool(static_cast<std::size_t>(error))));
    }
    return 0;
}
