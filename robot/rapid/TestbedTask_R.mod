MODULE TestbedTask_R(SYSMODULE)
  ! Task T_ROB_R (the right arm) of the testbed: its data for TestbedMotion and for
  ! the world zones. Load into task T_ROB_R only, with TestbedZones.sys and
  ! TestbedMotion.mod next to it (robot/README.md, "Install").
  !
  ! A SYSTEM module (issue 29): the POWER_ON event routine tb_zones (TestbedZones.sys)
  ! reads the zone constants below at every power on, also after "Reset RAPID", which
  ! removes every program module; so they live in a module that stays. main (the
  ! program's entry) is in TestbedMotion, the program module: RAPID wants it there.
  !
  ! The file this task reads, on the RAM disk: fixed per task, the name the driver
  ! uploads to (drivers/yumi/yumi_controller.py, program_file). The other arm's task
  ! reads its own file, so the two programs never share one.
  CONST string tb_name := "testbed_T_ROB_R.bin";
  ! The pusher, held by the CONTROLLER (issue 35): its frame and its load are these, and
  ! no program file changes them. tframe is the pusher's tip (the TCP the world zones
  ! supervise) measured on this robot with the FlexPendant's 4-point TCP method
  ! (robot/README.md, "The tool frame"); shipped: 184.2 mm down the flange's z (the
  ! SmartGripper fingers' TCP at 114.2 mm + the rod's 70 mm beyond them). Every program
  ! file carries the frame the operator side believes (the calibration's tool_z_mm);
  ! TestbedMotion refuses a file whose frame differs from this one by more than 1 mm or
  ! 0.5 deg, before any motion. After measuring, write the value here AND into the
  ! calibration files' tool_z_mm. The load is everything the flange carries: the YuMi
  ! SmartGripper that holds the pusher AND the pusher (robot/README.md, "The tool load",
  ! says where each number comes from and how a lab identifies its own):
  !   gripper (servo, camera, vacuum): 0.262 kg, CoG (7.8, 11.9, 50.7) mm, inertia
  !     0.00022, 0.00024, 0.00009 kgm2 (ABB's SmartGripper load table, the value the
  !     lab's published YuMi RAPID uses);
  !   pusher (estimate until weighed): 0.010 kg, a 100 mm rod of 10 mm diameter, its
  !     centre 134 mm down the tool z axis;
  !   together, about the joint centre of gravity: 0.272 kg, CoG (7.5, 11.5, 53.8) mm,
  !     inertia 0.0003, 0.00032, 0.00009 kgm2 (axes of tool0: aom [1,0,0,0]).
  TASK PERS tooldata tool_pusher := [TRUE,[[0,0,184.2],[1,0,0,0]],[0.272,[7.5,11.5,53.8],[1,0,0,0],0.0003,0.00032,0.00009]];
  ! The floor (mm, world frame = wobj0, the frame the driver's targets use): no
  ! MoveJ/MoveL target below it (checked in the file) and no TCP below it, anywhere
  ! (the world zone tb_wz_floor).
  CONST num tb_floor_z := 0;
  ! This arm's world zone (TestbedZones, tb_zones; robot/README.md, "The zones"): below
  ! tb_zone_z (mm, world) the TCP of tool_pusher must stay inside the xy box from
  ! tb_zone_lo to tb_zone_hi (x, y in mm, world; z unused). SET THESE FROM YOUR TABLE at
  ! install: the calibration's table_box_mm must lie inside the box, the other arm's
  ! workspace outside it, and tb_zone_z at or below the calibration's z_travel_mm.
  CONST pos tb_zone_lo := [125,-395,0];
  CONST pos tb_zone_hi := [495,-25,0];
  CONST num tb_zone_z := 80;
  ! The cell's speed caps, held by the CONTROLLER (issue 43; robot/README.md, "The limits
  ! a file cannot pass"): TestbedMotion refuses, before any motion, a program file with a
  ! speed above one of them, and runs every move after VelSet 100, tb_v_tcp_max. SET
  ! THESE FOR YOUR CELL (the lab, not the PC): tb_v_tcp_max (mm/s, the TCP) at or above
  ! the calibration's max_speed_mm_s (shipped 150, its default: the driver's every move
  ! runs at most that), or the driver's files are refused; tb_v_ori_max (deg/s, the
  ! tool's reorientation) and tb_v_reax_max (deg/s, axis 7, the arm angle: the YuMi's
  ! rotational external axis) at or above the driver's 100. A joint move (MoveAbsJ,
  ! MoveJ) is bounded by all three: speeddata has no per-axis speed.
  CONST num tb_v_tcp_max := 150;
  CONST num tb_v_ori_max := 100;
  CONST num tb_v_reax_max := 100;
ENDMODULE
